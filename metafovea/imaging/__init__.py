"""Imaging simulation: scenes in kelvin -> in-band radiance -> two channel images -> polariser mixing ->
microbolometer frames (a :class:`~metafovea.measurement.Measurement`).

Modules, in the order of the flow:

* :mod:`~metafovea.imaging.scene`: scenes over field angle and time (built-in, scikit-image pictures, files).
* :mod:`~metafovea.imaging.generator`: seeded random thermal scenes (``gen:KIND:SEED``) held out from tuning.
* :mod:`~metafovea.imaging.channel`: the foveal and perifoveal channels on the sensor crop (focal-plane pitch,
  field angles, ``cos^4`` relative illumination).
* :mod:`~metafovea.imaging.kernels`: PSF kernels per channel (providers: optics with its disk cache, Airy,
  Gaussian, explicit), the chromatic haze, field patches (:class:`~metafovea.imaging.kernels.ChannelOptics`).
* :mod:`~metafovea.imaging.render`: one channel's noise-free image of a scene (incremental for video scenes).
* :mod:`~metafovea.imaging.polarizer`: the simulated rotation (drawn phase and rate) of the polariser whose mixing
  ratio alpha :mod:`metafovea.polarizer` models.
* :mod:`~metafovea.imaging.sensor`: radiance to DN, temporal noise, low-rank FPN, ADC.
* :mod:`~metafovea.imaging.plan`: the error-budgeted simulation's planner (``simulate(..., tolerance_k=T)``): each
  effect's estimated contribution for a scene, the cheapest model within the budget, the plan table.
* :mod:`~metafovea.imaging.simulate`: end to end (:func:`simulate`), and the files of ``metafovea simulate``
  (:func:`simulate_to_files`: Measurement, TIFF stack, preview).
* :mod:`~metafovea.imaging.ablate`: the truth a plan's estimates are tested against (the full model with and without
  each effect) and a model's realised error against the full one.
"""


from metafovea.imaging.channel import Channel, channels_for
from metafovea.imaging.generator import GENERATOR_KINDS, generated_scene, held_out_scenes, tuning_scenes
from metafovea.imaging.kernels import ExplicitPSF, Kernel
from metafovea.imaging.polarizer import Polarizer
from metafovea.imaging.scene import Scene, SceneGeometry, list_scenes, make_scene
from metafovea.imaging.sensor import FixedPattern, SensorModel
from metafovea.imaging.simulate import (
    SimulationOptions,
    preview_figure,
    simulate,
    simulate_to_files,
    write_preview,
    write_tiff,
)

__all__ = ["Scene", "SceneGeometry", "GENERATOR_KINDS", "generated_scene", "held_out_scenes", "tuning_scenes",
           "list_scenes", "make_scene", "FixedPattern", "SensorModel", "SimulationOptions", "simulate",
           "simulate_to_files", "preview_figure", "write_preview", "write_tiff", "Channel", "ExplicitPSF", "Kernel",
           "Polarizer", "channels_for"]
