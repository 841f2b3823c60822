"""Shared fixtures: the paper's configuration and models built once per session; a private ROS 2 graph."""

import os
import random
from collections.abc import Iterator

import pytest

from panel_rig.config import load_config
from panel_rig.model.aeroelastic import AeroelasticModel


@pytest.fixture(scope="session")
def cfg():
    return load_config()


@pytest.fixture(scope="session")
def model(cfg):
    return AeroelasticModel(cfg)


@pytest.fixture(scope="module")
def ros_env(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, str]]:
    """A private ROS 2 graph for one test module: a random domain (102-200, away from the default 0 of a user's own
    nodes), discovery on localhost only, logs in a temporary directory. Applied to this process (the rclpy clients
    a test makes join it) and restored afterwards; yields the whole environment, for the nodes a test starts."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("ROS_DOMAIN_ID", str(random.randint(102, 200)))  # programs: 1..101 (PRIVATE_DOMAINS)
        mp.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
        mp.setenv("ROS_LOG_DIR", str(tmp_path_factory.mktemp("ros_log")))
        yield dict(os.environ)
