"""The C side of smartjoint as package data: ``runtime/`` holds the hand-written E2E runtime and
replay harness that the code generator and the bench use (``common/package_data.py``).
``generated/`` is the reference output kept in the source tree; it is not installed."""

__all__: list[str] = []  # C sources only: nothing to import
