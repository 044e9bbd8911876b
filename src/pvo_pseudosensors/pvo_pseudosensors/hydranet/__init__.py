"""HydraNet (thesis ch. 7): relative rotations with epistemic and aleatoric covariance. :mod:`.quaternion` holds
the rotation average, Sigma_e and the NLL (eqs. 7.14-7.17); :mod:`.oned` the one-dimensional study of §7.4.2
(Figs. 7.4-7.5)."""
