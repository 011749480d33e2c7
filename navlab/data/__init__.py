"""Loaders for the real recordings and a documented generic CSV format.

The data are never part of the repository: they are read from ``../shared/data`` (relative to
the repository root), from the directory in the environment variable ``NAVLAB_DATA``, or from a
path the caller gives. Every loader returns typed, tidy structures (pandas DataFrames whose
column names carry their units) and raises :class:`navlab.errors.NavlabError` naming the file,
the line and column and what to change when a file is missing, empty, truncated or holds
NaN / absurd values.
"""

from navlab.data.loaders import (
    DriveRecording,
    PseudorangeRecording,
    data_root,
    load_generic,
    load_pseudoranges,
    read_pseudorange_csv,
    read_smartloc,
    rtkx_drive_0708,
    smartloc_berlin_pp,
)

__all__ = [
    "DriveRecording",
    "PseudorangeRecording",
    "data_root",
    "load_generic",
    "load_pseudoranges",
    "read_pseudorange_csv",
    "read_smartloc",
    "rtkx_drive_0708",
    "smartloc_berlin_pp",
]
