"""Imaging simulation: scenes in kelvin -> in-band radiance -> two channel images -> polariser mixing ->
microbolometer frames (a :class:`Measurement`).

Modules: :mod:`~metafovea.imaging.scene` (scenes over field angle and time),
:mod:`~metafovea.imaging.system` (channels,
PSFs, haze, polariser), :mod:`~metafovea.imaging.sensor` (noise, FPN, ADC),
:mod:`~metafovea.imaging.simulate` (end to end).
"""


from metafovea.imaging.scene import Scene, SceneGeometry, list_scenes, make_scene
from metafovea.imaging.sensor import FixedPattern, SensorModel
from metafovea.imaging.simulate import SimulationOptions, simulate, write_preview, write_tiff
from metafovea.imaging.system import Channel, ExplicitPSF, Kernel, Polarizer, channels_for

__all__ = ["Scene", "SceneGeometry",
           "list_scenes", "make_scene", "FixedPattern", "SensorModel", "SimulationOptions", "simulate",
           "write_preview", "write_tiff", "Channel", "ExplicitPSF", "Kernel", "Polarizer", "channels_for"]
