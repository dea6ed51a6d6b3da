"""smartjoint: semi-active friction joints, from the truss FE model to tested C firmware.

The pipeline's stages live in subpackages named after the design card's folders:
``smartjoint.design`` (models and control design), ``smartjoint.codegen`` (C generation),
``smartjoint.bench`` (software-in-the-loop bench). The command line is ``smartjoint.cli``.
"""

__version__ = "0.1.0"
