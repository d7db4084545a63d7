"""A small renderer: a unit sphere under an environment map and directional lights, with fixed
stratified light samples shared by every BRDF (so a ground truth and a model share their noise),
written as linear EXR, tone-mapped PNG and error maps."""

from .lights import DirectionalLight, EnvironmentMap, LightSamples, gather
from .output import error_map, tonemap, write_error_map, write_exr, write_png
from .render import bundle_brdf, model_brdf, render
from .scene import SphereScene, ball_scene, sphere_scene

__all__ = [
    "DirectionalLight", "EnvironmentMap", "LightSamples", "SphereScene", "ball_scene", "bundle_brdf", "error_map", "gather",
    "model_brdf", "render", "sphere_scene", "tonemap", "write_error_map", "write_exr", "write_png",
]
