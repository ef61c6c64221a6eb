from glob import glob

from setuptools import find_packages, setup

package_name = "uav_landing_vision"
# The repository's config/ folder, so that an installed package finds its defaults. colcon runs
# this file from the package folder; anywhere else the globs would find nothing, so say so.
configs, scenarios = glob("../../config/*.yaml"), glob("../../config/scenarios/*.yaml")
if not configs or not scenarios:
    raise SystemExit("setup.py: ../../config/ not found; build the package from its own folder (colcon does)")

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test", "tests"]),
    package_data={package_name: ["render/shaders/*.vert", "render/shaders/*.frag"]},
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/launch", glob("launch/*.py")),
        ("share/" + package_name + "/models", glob("models/*")),
        ("share/" + package_name + "/config", configs),
        ("share/" + package_name + "/config/scenarios", scenarios),
    ],
    install_requires=["setuptools"],
    zip_safe=False,  # shaders are read from next to the modules
    maintainer="uav-landing-vision maintainers",
    maintainer_email="uav-landing-vision@example.org",
    description="Monocular 6-DoF pose tracking of a fixed-wing UAV landing on a ship.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "uav-landing = uav_landing_vision.cli:main",
            "undistort = uav_landing_vision.nodes.undistort:main",
            "detector = uav_landing_vision.nodes.detector:main",
            "pose_boosting = uav_landing_vision.nodes.pose_boosting:main",
            "tracker = uav_landing_vision.nodes.tracker:main",
            "evaluator = uav_landing_vision.nodes.evaluator:main",
            "bag_player = uav_landing_vision.nodes.bag_player:main",
            "gcs_bridge = uav_landing_vision.nodes.gcs_bridge:main",
        ],
    },
)
