"""Real camera recordings into the Measurement format (``metafovea import``).

Files:

* :mod:`~metafovea.recordings.read`: the readers (16-bit TIFF stacks with tifffile, HDF5 with h5py, MAT v5 with
  scipy.io and v7.3 with h5py, FLIR's files through :mod:`~metafovea.recordings.flir`) into one
  :class:`~metafovea.recordings.read.Recording` (frames, timestamps, polariser state, Planck constants, object
  parameters, scalar metadata);
* :mod:`~metafovea.recordings.flir`: FLIR's radiometric JPEG (flyr), FFF and SEQ (flirpy), ``pip install
  "metafovea[flir]"``;
* :mod:`~metafovea.recordings.timestamps`: frame times and the timing check (duplicated frames removed, dropped
  frames and non-uniform intervals detected and recorded);
* :mod:`~metafovea.recordings.calibration`: counts to kelvin, FLIR's Planck constants (with a FLIR file's
  emissivity, reflected temperature, air and window) or a two-point blackbody calibration, as the Measurement's
  ``dark_dn`` / ``dn_per_k_300K`` / ``radiometry``;
* :mod:`~metafovea.recordings.convert`: :func:`to_measurement` and :func:`import_recording`, the steps in order.

InfraTec's IRB and FLIR's CSQ are refused with the export to make instead: no maintained Python reader decodes them
(README, "Reconstructing a real recording").
"""

from metafovea.recordings.calibration import GAIN_MODES, PlanckConstants, Radiometric, SceneParameters
from metafovea.recordings.convert import POLARIZER_UNITS, ImportOptions, import_recording, to_measurement
from metafovea.recordings.read import FORMATS, FRAME_AXES, TIME_UNITS, Recording, read_recording
from metafovea.recordings.timestamps import TimingReport, check_timing

__all__ = ["FORMATS", "FRAME_AXES", "GAIN_MODES", "POLARIZER_UNITS", "TIME_UNITS", "ImportOptions", "PlanckConstants",
           "Radiometric", "Recording", "SceneParameters", "TimingReport", "check_timing", "import_recording",
           "read_recording", "to_measurement"]
