"""The structure (paper Sections 2–3): the design file, the truss FE model, its modes, model
updating, joint placement and the neutral model export."""
