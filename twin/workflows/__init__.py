"""The workflows, side by side: the laser loop (:mod:`.loop`), locate-then-machine
(:mod:`.locate`, document 001), CMM programs (:mod:`.cmm`, document 002) and the arm's base
placement (:mod:`.placement`). Each imports the shared stages below it, never another
workflow (the import contract in ``pyproject.toml`` fails CI otherwise); studies, the
environments and the CLI sit above them.
"""
