"""Control design (paper Section 5): the SISO law, the clipped-optimal LQG, the controller
artefact and the closed-loop study."""
