"""DPC-Net (thesis ch. 6): learned SE(3) corrections to the stereo VO over Δp frames. :mod:`.loss` holds the
SE(3) and SO(3) losses with their analytic Jacobians (eqs. 6.2-6.14) and the target covariance (eq. 6.6)."""
