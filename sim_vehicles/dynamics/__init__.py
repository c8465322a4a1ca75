"""Vehicle motion (eq. 2, vectorised over the fleet) and the local <-> geodetic frame."""
