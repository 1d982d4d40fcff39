"""Former home of the generators and the meshing kernel, kept for one remaining caller.

``tests/test_symmetric.py`` still builds a test plate from the kernel under its old private
names; these aliases keep that test working until it imports :mod:`twin.parts.kernel`, after
which this module can be deleted. New code uses :mod:`twin.parts` and :mod:`twin.parts.kernel`.
"""

from twin.parts import kernel

_sample_profile = kernel.sample_profile
_line = kernel.line_segment
_revolve = kernel.revolve
_box_patches = kernel.box_patches
_assemble = kernel.assemble
