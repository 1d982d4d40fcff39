"""The scan-cell digital twin: scenarios, MuJoCo cell, laser sensor, scans, replay, CLI.

For notebooks and scripts: ``twin.run(scenario)``, ``twin.locate(scenario)`` and
``twin.study(study_file, out)`` (:mod:`twin.api`). Importing ``twin`` stays light: the
workflows load on the first call.
"""

import sys

from twin import _starting

_starting.guard()  # the command line (twin, python -m twin): a signal while it starts ends it cleanly

# trimesh imports the OpenCASCADE wheel (cascadio) whenever it is installed, to offer STEP
# loading; that adds its libraries to every command's start-up, and a SIGTERM that arrives while
# they initialise ends the process with a segmentation fault. The twin reads STEP itself
# (twin.formats.step), importing cascadio there only; here trimesh is told it is absent.
sys.modules.setdefault("cascadio", None)  # type: ignore[arg-type]

from twin import _gym_registration  # noqa: E402
from twin.api import locate, run, study  # noqa: E402
from twin.errors import TwinError  # noqa: E402

__all__ = ["TwinError", "locate", "run", "study"]

_gym_registration.install()   # gymnasium.make("twin/ActiveScan-v0") after import twin
