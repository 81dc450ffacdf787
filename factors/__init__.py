"""Custom GTSAM factors of fgcal (installed as ``fgcal.factors``)."""
