"""Infrastructure every stage may import, and that imports no stage: the error types
(``errors``), the native (cffi) build cache (``native``), the package's data files
(``package_data``) and figures written as files (``figures``)."""

from smartjoint.common.errors import DesignError, ModelError, SmartjointError

__all__ = ["DesignError", "ModelError", "SmartjointError"]
