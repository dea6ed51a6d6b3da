"""C code generation: jinja2 templates → fixed-step C99 controllers (``generate``), compiled and
loaded with cffi behind the Python controller interface (``build``)."""
