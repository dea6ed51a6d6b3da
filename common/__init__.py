"""Infrastructure every stage may import, and that imports no stage: the error types, the native
(cffi) build cache and the package's data files."""
