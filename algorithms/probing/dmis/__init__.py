"""DMIS 5.3: the writer and the strict reader of the twin's own programs
(:mod:`~algorithms.probing.dmis.strict`), the reader of real part programs
(:mod:`~algorithms.probing.dmis.reader`: lexer, expressions, the program's meaning in
:mod:`~algorithms.probing.dmis.model`), and the evaluation of measured features and
tolerances with DMIS output (:mod:`~algorithms.probing.dmis.evaluation`)."""

from algorithms.probing.dmis.strict import (
    DMIS_VERSION,
    parse_dmis,
    read_dmis,
    write_dmis,
    write_dmis_file,
)

__all__ = ["DMIS_VERSION", "parse_dmis", "read_dmis", "write_dmis", "write_dmis_file"]
