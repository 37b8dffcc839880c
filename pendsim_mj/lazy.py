"""Names a package exports but imports on first use (PEP 562), so that importing the package stays light.

A facade (``pendsim_mj``, ``pendsim_mj.rig``, ``pendsim_bridge``, ``pendsim_bridge.io``) lists
where each of its heavier names is defined and installs the two module functions this returns::

    _LAZY = {"simulate": "pendsim_mj.engines.simulation", "nonlinear": "pendsim_mj.nonlinear"}
    if TYPE_CHECKING:  # what mypy and editors see: the real names
        from pendsim_mj import nonlinear
        from pendsim_mj.engines.simulation import simulate
    else:
        __getattr__, __dir__ = lazy.exports(__name__, _LAZY)

The first ``pendsim_mj.simulate`` imports ``pendsim_mj.engines.simulation`` (and with it MuJoCo)
and keeps the function in the package, so later look-ups are plain attribute reads. A name whose
source is the package's own submodule of that name (``nonlinear``) is that submodule. Sources may
be relative to the package (``".io.recording"``). ``__getattr__`` stays out of mypy's sight (the
``else`` branch above), so that a misspelt import is still an error there.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable, Mapping


def exports(package: str, lazy: Mapping[str, str]) -> tuple[Callable[[str], object], Callable[[], list[str]]]:
    """The module ``__getattr__`` and ``__dir__`` of ``package`` (its ``__name__``), whose names
    ``lazy`` maps to the modules defining them (absolute, or relative to the package)."""
    namespace = sys.modules[package].__dict__

    def __getattr__(name: str) -> object:
        source = lazy.get(name)
        if source is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        module = importlib.import_module(source, package)
        value = module if module.__name__ == f"{package}.{name}" else getattr(module, name)
        namespace[name] = value
        return value

    def __dir__() -> list[str]:
        return sorted({*namespace, *lazy})

    return __getattr__, __dir__
