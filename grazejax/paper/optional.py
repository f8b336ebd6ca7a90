"""SciPy, which the paper's independent checks use and grazejax does not install."""

from __future__ import annotations

import importlib
from types import ModuleType

SCIPY_EXTRA = "paper"


def scipy_module(name: str) -> ModuleType:
    """`scipy.<name>` (e.g. "integrate"), or an ImportError that says what to install.

    SciPy is not a dependency of grazejax: the independent checks of `grazejax reproduce`
    (closed forms solved by Brent's method, reference integrations by `solve_ivp`) need the
    `paper` extra.
    """
    try:
        return importlib.import_module(f"scipy.{name}")
    except ImportError as error:
        raise ImportError(
            f"the paper's independent checks need SciPy (scipy.{name}), which grazejax does "
            f"not install: pip install 'grazejax[{SCIPY_EXTRA}]' (or pip install scipy)"
        ) from error
