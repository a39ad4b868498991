"""Two radars, one air picture: track-to-track association (statistical, bias-robust, the seed's network),
fusion by covariance intersection, and users' track tables read and associated at common times."""
