"""Register the gymnasium environments when gymnasium is imported, without importing it.

``import twin`` must stay light (the command line starts in a tenth of a second; gymnasium's
import alone takes twice that), yet ``gymnasium.make("twin/ActiveScan-v0")`` should work after
``import twin``. So: if gymnasium is already imported, register now; otherwise a finder on
``sys.meta_path`` waits for gymnasium's import and registers right after it.
"""

from __future__ import annotations

import importlib.abc
import importlib.util
import sys


def _register() -> None:
    import twin.env  # noqa: F401  (registers on import)


class _AfterGymnasium(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Finds ``gymnasium`` with the other finders and registers once its module has run."""

    def find_spec(self, fullname, path=None, target=None):
        if fullname != "gymnasium":
            return None
        sys.meta_path.remove(self)
        spec = importlib.util.find_spec(fullname)
        if spec is None or spec.loader is None:
            return spec
        self.loader = spec.loader
        spec.loader = self
        return spec

    def create_module(self, spec):
        return self.loader.create_module(spec)

    def exec_module(self, module):
        self.loader.exec_module(module)
        _register()


def install() -> None:
    """Register now if gymnasium is loaded, else when it is (at most once)."""
    if "gymnasium" in sys.modules:
        _register()
    elif not any(isinstance(f, _AfterGymnasium) for f in sys.meta_path):
        sys.meta_path.insert(0, _AfterGymnasium())
