"""The Cycles reference baker lives with the tests that check it (tests/cycles_reference.py);
the bench uses the same module."""
import importlib.util as _util
import sys as _sys
from pathlib import Path as _Path

_spec = _util.spec_from_file_location("pdic_cycles_reference",
                                      _Path(__file__).resolve().parents[1] / "tests" / "cycles_reference.py")
_module = _util.module_from_spec(_spec)
_sys.modules[_spec.name] = _module  # dataclasses resolve string annotations through sys.modules
_spec.loader.exec_module(_module)
globals().update({k: v for k, v in vars(_module).items() if not k.startswith("__")})
