"""HydraNet (thesis ch. 7): relative rotations with epistemic and aleatoric covariance. :mod:`.oned` holds the
one-dimensional study of §7.4.2 (Figs. 7.4-7.5)."""
