"""Importers: real recordings -> the same :class:`~physynth.records.Trace` records the generator makes.

Each importer returns ``(trace, report)``; the :class:`ImportReport` counts every row that was read,
kept, repaired, dropped or flagged, so nothing is dropped silently. Bad input raises
:class:`~physynth.errors.RecordingError` with one line naming the file and the problem.

- :func:`import_csv`: the generic recording format (docs/recording-format.md)
- :func:`import_hanyang`: one dynamic run of the Hanyang outdoor UWB dataset
- :func:`import_hanyang_static`: the Hanyang static range sweeps as a table (range bias)
- :func:`import_broad`: one BROAD IMU/optical trial
"""

from ._common import ImportReport
from .broad import import_broad
from .csv_format import import_csv
from .hanyang import import_hanyang, import_hanyang_static

__all__ = ["ImportReport", "import_broad", "import_csv", "import_hanyang", "import_hanyang_static"]
