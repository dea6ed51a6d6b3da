"""The friction joints (paper Section 3.2): the LuGre law (Eq. 1–3), the isolated-joint rig, its
records and the identification of the LuGre parameters."""
