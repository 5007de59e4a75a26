"""One client method per command of the table, made at import.

Names, parameters, docstrings and signatures all come from lluav-core's
table (through ``_core``); this module only shapes them into Python. The
stub generator (``python/tools/gen_stub.py``) renders the same signatures
and docstrings, so editors and ``help()`` say the same thing.
"""

from __future__ import annotations

import inspect
from typing import Any, Callable

from . import _core

RETURNS = "dict[str, Any]"


def param_annotation(param: _core.Param) -> str:
    """The parameter's annotation, ``| None`` added when it is optional."""
    return f"{param.annotation} | None" if param.optional else param.annotation


def gates(spec: _core.Spec) -> list[str]:
    """The gates that may refuse the command, in words."""
    said = []
    if spec.admin_only:
        said.append("admin sessions only")
    if not spec.run_on_arm:
        said.append("refused while the vehicle is armed")
    if not spec.run_in_lock:
        said.append("refused in lock mode unless the session is admin")
    return said


def docstring(spec: _core.Spec) -> str:
    """The method's docstring."""
    lines = [spec.summary, "", f"Sends ``{spec.usage}`` (command id {spec.id})."]
    refused = gates(spec)
    if refused:
        lines.append("Gates: " + "; ".join(refused) + ".")
    lines += [
        "",
        "Returns the whole response object (``ret`` 0). Raises InvalidArguments",
        "before sending when the arguments do not fit, CommandError when ``ret``",
        "is not 0, ConnectionError when the connection fails.",
    ]
    return "\n".join(lines)


def signature(spec: _core.Spec) -> inspect.Signature:
    """The method's signature, ``self`` first."""
    kind = inspect.Parameter.POSITIONAL_OR_KEYWORD
    params = [inspect.Parameter("self", kind)]
    for p in spec.params:
        default = None if p.optional else inspect.Parameter.empty
        params.append(inspect.Parameter(p.name, kind, default=default, annotation=param_annotation(p)))
    return inspect.Signature(params, return_annotation=RETURNS)


def command_id(name: str) -> int:
    """The id of the command called ``name`` in the table."""
    for spec in _core.TABLE:
        if spec.name == name:
            return spec.id
    raise LookupError(f"the command table has no {name!r}")


LOGIN = command_id("login")


def install(cls: type, make: Callable[[int], Callable[..., Any]]) -> None:
    """Adds ``make(id)`` to ``cls`` under each command's name.

    A name that is taken by the class itself is a defect of this package
    (the table gained a command called like a client method): fail loudly.
    """
    for spec in _core.TABLE:
        if not spec.name.isidentifier() or hasattr(cls, spec.name):
            raise RuntimeError(f"command {spec.name!r} cannot become a method of {cls.__name__}")
        method = make(spec.id)
        method.__name__ = spec.name
        method.__qualname__ = f"{cls.__name__}.{spec.name}"
        method.__doc__ = docstring(spec)
        method.__signature__ = signature(spec)  # type: ignore[attr-defined]
        setattr(cls, spec.name, method)
