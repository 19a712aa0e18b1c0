"""The per-pair work of ``mipnet infer``, shared by the single-process command (:mod:`mipnet.cli.infer`) and
the Ray pipeline (:mod:`mipnet.distributed`): which pairs a path or glob names and the names of their outputs
(:mod:`.pairs`), reading a pair, running it and writing its outputs (:mod:`.outputs`), and what counts as a
pair's failure (:mod:`.failures`)."""

from .failures import USER_ERRORS, describe, naming
from .outputs import OutputOptions, OutputWriter, infer_pair
from .pairs import folder_pair, output_names, read_pair, resolve_pairs

__all__ = ["USER_ERRORS", "describe", "naming", "OutputOptions", "OutputWriter", "infer_pair", "folder_pair",
           "output_names", "read_pair", "resolve_pairs"]
