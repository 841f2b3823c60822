"""panel_rig's Fast DDS profile is used unless the user configured Fast DDS (panel_rig/ros/discovery.py)."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from panel_rig.ros.discovery import CWD_PROFILE, PROFILE, PROFILE_ENV, use_quick_announcements


def test_the_profile_sets_only_a_half_second_announcement_period() -> None:
    ns = {"p": "http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles"}
    root = ET.parse(PROFILE).getroot()
    participant = root.find("p:participant", ns)
    assert participant is not None and participant.get("is_default_profile") == "true"
    period = participant.find("p:rtps/p:builtin/p:discovery_config/p:leaseAnnouncement", ns)
    assert period is not None
    assert int(period.find("p:sec", ns).text) + int(period.find("p:nanosec", ns).text) * 1e-9 == 0.5
    assert len(participant.find("p:rtps/p:builtin/p:discovery_config", ns)) == 1  # nothing else changed


def test_the_profile_is_pointed_at_when_nothing_is_configured(tmp_path: Path) -> None:
    env: dict[str, str] = {}
    assert use_quick_announcements(env, tmp_path)
    assert env == {PROFILE_ENV[0]: str(PROFILE)}


@pytest.mark.parametrize("name", PROFILE_ENV)
def test_a_user_s_own_profile_file_is_left_alone(tmp_path: Path, name: str) -> None:
    env = {name: "/home/user/my_dds.xml"}
    assert not use_quick_announcements(env, tmp_path)
    assert env == {name: "/home/user/my_dds.xml"}


def test_a_profile_in_the_working_directory_is_left_alone(tmp_path: Path) -> None:
    (tmp_path / CWD_PROFILE).write_text("<profiles/>")
    env: dict[str, str] = {}
    assert not use_quick_announcements(env, tmp_path)
    assert env == {}
