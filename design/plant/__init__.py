"""The nonlinear closed-loop plant (paper Eq. 12): the controller interface, the discretisation,
the simulation schemes and their kernels."""
