"""Software-in-the-loop bench (plant ↔ compiled controller ↔ CAN). Arrives with issue 7."""
