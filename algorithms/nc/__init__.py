"""NC programs: document 003's last step, the located pose applied to a CAM program.

* :mod:`.gcode`: a 3-axis G-code program (ISO 6983 words G0/G1, X Y Z F, G20/G21, G90/G91)
  written from tool-tip passes and read back into moves;
* :mod:`.relocate`: the CAM program's cutter locations (programmed in the CAD frame) moved to
  where the part is (``T_machine_workpiece``), for a ball-end tool;
* :mod:`.cam`: a ball-end raster finishing program of a mesh (drop-cutter on the surface's
  samples), the CAM program the benchmark and the tests relocate.
"""

from algorithms.nc.cam import drop_cutter_raster
from algorithms.nc.gcode import GCodeError, Move, program_text, read_gcode, write_gcode
from algorithms.nc.relocate import relocate_program, relocate_tool_tips

__all__ = ["GCodeError", "Move", "drop_cutter_raster", "program_text", "read_gcode", "relocate_program",
           "relocate_tool_tips", "write_gcode"]
