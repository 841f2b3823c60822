"""ament_python package panel_rig (also pip-installable outside a ROS workspace)."""
from glob import glob

from setuptools import find_packages, setup

PACKAGE = "panel_rig"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["tests", "tests.*", "benchmarks"]),
    package_data={"panel_rig.ros": ["fastdds_profile.xml"]},  # the DDS announcement period (ros/discovery.py)
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", glob("config/*.yaml")),
        (f"share/{PACKAGE}/config/studies", glob("config/studies/*.yaml")),
        (f"share/{PACKAGE}/launch", glob("launch/*.py")),
    ],
    python_requires=">=3.10",
    install_requires=["numpy>=1.24", "scipy>=1.10", "pyyaml>=6", "matplotlib>=3.7", "numba>=0.60"],
    extras_require={
        # ROS 2 Jazzy from PyPI, for machines without a ROS install.
        "ros": ["ros-rclpy==7.1.6", "ros-common-interfaces==5.3.6", "ros-rmw-fastrtps-cpp==8.4.3"],
        "record": ["mcap>=1.5.0", "mcap-ros2-support>=0.5"],
        "viz": ["rerun-sdk==0.41.0"],
        "test": ["pytest>=8", "ruff>=0.6", "rosbags>=0.10", "catkin_pkg>=1.0",
                 "colcon-core", "colcon-ros", "colcon-python-setup-py", "colcon-package-information"],
        # parameter studies (panel_rig/studies, `panel-rig study`): Dask's distributed scheduler, the results as
        # one xarray Dataset in Zarr, a progress bar
        "study": ["dask[distributed]>=2026.1", "xarray>=2025.1", "zarr>=3", "tqdm>=4.66"],
    },
    zip_safe=True,
    maintainer="panel_rig developers",
    maintainer_email="panel-rig@example.com",
    description="Wind-tunnel aeroelastic panel rig emulator (Tang & Dowell 2002)",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "panel-rig = panel_rig.entry:panel_rig",
            "rig_node = panel_rig.entry:rig_node",
            "rig_operator = panel_rig.entry:rig_operator",
            "rig_controller = panel_rig.entry:rig_controller",
        ],
    },
)
