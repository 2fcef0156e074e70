"""MuJoCo model templates shipped as package data (see ``roadtruth.harness.truth.car_model``)."""

from importlib.resources import files


def template_path(name: str) -> str:
    """Absolute path of a shipped MJCF template, e.g. ``template_path("car.xml")``."""
    return str(files(__package__) / name)
