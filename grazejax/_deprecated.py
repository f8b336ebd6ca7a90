"""Names that moved: the old spelling keeps working for a while, with a warning that says
what to write instead."""

from __future__ import annotations

import functools
import warnings


def renamed_keyword(old: str, new: str, why: str):
    """Decorate a function whose keyword `old` is now `new`: a call with `old` warns
    (`DeprecationWarning`, naming `new` and `why`) and passes its value as `new`; a call
    with both is a `TypeError`."""

    def decorate(fn):
        @functools.wraps(fn)
        def wrapper(*args, **kwargs):
            if old in kwargs:
                if new in kwargs:
                    raise TypeError(f"{fn.__name__}() got both {old!r} and {new!r}; "
                                    f"pass {new!r} only")
                warnings.warn(f"{fn.__name__}(): {old!r} is renamed {new!r} ({why})",
                              DeprecationWarning, stacklevel=2)
                kwargs[new] = kwargs.pop(old)
            return fn(*args, **kwargs)

        return wrapper

    return decorate


NEWTON_STEPS = "Newton iterations; `max_steps` is simulate's number of solver steps"
"""Why `max_steps` became `max_newton_steps` in the orbit solvers."""
