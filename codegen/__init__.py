"""C code generation (jinja2 templates → fixed-step C99, cffi build). Arrives with issue 6."""
