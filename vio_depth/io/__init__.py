"""Reading sequences and writing results."""

from .base import Sequence, SequenceFormat, available_formats, open_sequence, register_format

__all__ = ["Sequence", "SequenceFormat", "available_formats", "open_sequence", "register_format"]
