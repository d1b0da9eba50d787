"""semcityloc: 6DoF UAV localization against semantic 3D city models.

The pipeline reads a city model (``semcityloc.citymodel``), renders semantic masks and depth from
hypothesised poses (``semcityloc.render``) and aligns them with the query's segmentation and depth.

``SemanticClass`` is loaded on first use (``__getattr__``): ``semcityloc.classes`` imports numpy, and the
``semcityloc`` console script (``cli.entry``) imports this package before it can catch a Ctrl-C, so the
less this module imports, the sooner a Ctrl-C is one line instead of a traceback.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from semcityloc.errors import SemCityLocError

if TYPE_CHECKING:
    # for type checkers only: at run time ``__getattr__`` below imports it on first use
    from semcityloc.classes import SemanticClass

__all__ = ["SemCityLocError", "SemanticClass", "__version__"]
__version__ = "0.1.0"


def __getattr__(name: str) -> Any:
    """``semcityloc.SemanticClass``, imported when first asked for (module docstring)."""
    if name == "SemanticClass":
        # lazy: numpy (via semcityloc.classes) not on `import semcityloc`, which the console script does first
        from semcityloc.classes import SemanticClass

        return SemanticClass
    raise AttributeError(f"module 'semcityloc' has no attribute {name!r}")
