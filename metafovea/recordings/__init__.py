"""Real camera recordings into the Measurement format (``metafovea import``).

Files:

* :mod:`~metafovea.recordings.read`: the readers (16-bit TIFF stacks with tifffile, HDF5 with h5py, MAT v5 with
  scipy.io and v7.3 with h5py) into one :class:`~metafovea.recordings.read.Recording` (frames, timestamps,
  polariser state, Planck constants, scalar metadata);
* :mod:`~metafovea.recordings.timestamps`: frame times and the timing check (duplicated frames removed, dropped
  frames and non-uniform intervals detected and recorded);
* :mod:`~metafovea.recordings.calibration`: counts to kelvin, FLIR's Planck constants or a two-point blackbody
  calibration, as the Measurement's ``dark_dn`` / ``dn_per_k_300K`` / ``radiometry``;
* :mod:`~metafovea.recordings.convert`: :func:`to_measurement` and :func:`import_recording`, the steps in order.

Vendor radiometric formats (FLIR radiometric JPEG through flyr, InfraTec) are not read: no sample file ships with
a package on the index to test a reader on (README, "Reconstructing a real recording").
"""

from metafovea.recordings.calibration import GAIN_MODES, PlanckConstants, Radiometric
from metafovea.recordings.convert import POLARIZER_UNITS, ImportOptions, import_recording, to_measurement
from metafovea.recordings.read import FORMATS, FRAME_AXES, TIME_UNITS, Recording, read_recording
from metafovea.recordings.timestamps import TimingReport, check_timing

__all__ = ["FORMATS", "FRAME_AXES", "GAIN_MODES", "POLARIZER_UNITS", "TIME_UNITS", "ImportOptions", "PlanckConstants",
           "Radiometric", "Recording", "TimingReport", "check_timing", "import_recording", "read_recording",
           "to_measurement"]
