"""C code generation: the controller design artefact → fixed-step C99 firmware.

Owns the jinja2 templates (``templates/``) and everything between the artefact and a compiled,
placed folder: the shared rendering rules (``rendering``: environment, banner, literals, the
checks before any C is rendered), the names that may become C identifiers (``identifiers``),
the controllers (``generate.render``) and the CAN message layer (``can_layer``), writing and
placing a set of files (``output``), compiling generated C and taking its cffi declarations from
the generated headers (``build``), the controllers compiled behind the Python controller
interface (``controllers``) and the back-to-back check against the Python reference
(``backtoback``). The ``smartjoint codegen`` pipeline is ``generate.generate``.

May import ``smartjoint.common`` and ``smartjoint.design`` (the artefact, the CAN protocol of
``design/network``, the plant interface); never ``smartjoint.bench``, which builds on this.
"""

from smartjoint.codegen.backtoback import back_to_back
from smartjoint.codegen.build import FLAGS, check_folder, compile_object, declarations
from smartjoint.codegen.can_layer import check_can, render_can
from smartjoint.codegen.controllers import CompiledLaw, Controllers, compile_controllers
from smartjoint.codegen.generate import render
from smartjoint.codegen.identifiers import check_names, check_prefix
from smartjoint.codegen.output import Placed, place, write
from smartjoint.codegen.rendering import banner, environment, literal

__all__ = [
    "FLAGS",
    "CompiledLaw",
    "Controllers",
    "Placed",
    "back_to_back",
    "banner",
    "check_can",
    "check_folder",
    "check_names",
    "check_prefix",
    "compile_controllers",
    "compile_object",
    "declarations",
    "environment",
    "literal",
    "place",
    "render",
    "render_can",
    "write",
]
