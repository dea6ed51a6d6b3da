"""Model reduction of the linear subsystem (paper Section 4): balanced mode selection and Krylov
correction vectors."""
