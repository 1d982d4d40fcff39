"""The scan-cell digital twin: scenarios, MuJoCo cell, laser sensor, scans, replay, CLI.

For notebooks and scripts: ``twin.run(scenario)``, ``twin.locate(scenario)`` and
``twin.study(study_file, out)`` (:mod:`twin.api`). Importing ``twin`` stays light: the
workflows load on the first call.
"""

from twin.api import locate, run, study
from twin.errors import TwinError

__all__ = ["TwinError", "locate", "run", "study"]
