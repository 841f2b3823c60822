"""Shared fixtures: the paper's configuration and models built once per session."""

import pytest

from panel_rig.config import load_config
from panel_rig.model.aeroelastic import AeroelasticModel


@pytest.fixture(scope="session")
def cfg():
    return load_config()


@pytest.fixture(scope="session")
def model(cfg):
    return AeroelasticModel(cfg)
