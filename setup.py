"""scene_recon: one ament_python package holding the ROS-free core packages and the ROS 2 nodes.

Installable two ways:
* `colcon build` on a stock ROS 2 (Kilted/Jazzy) install: console scripts land in
  `lib/scene_recon` (see setup.cfg) so `ros2 run scene_recon <node>` finds them, and launch/config
  files under `share/scene_recon`;
* `pip install -e .` into the project venv (`make setup`): console scripts in `.venv/bin`.
"""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "scene_recon"

setup(
    name=PACKAGE,
    version="0.1.0",
    description="RGB-D stream to an interactive, kinematic scene (panoptic mapping, contact graph, CAD replacement)",
    packages=[
        *find_packages(
        include=[
            "recon_core",
            "recon_core.*",
            "scene_recon",
            "scene_recon.*",
            "panoptic_mapping",
            "panoptic_mapping.*",
            "scene_graph",
            "scene_graph.*",
            "cad_replacement",
            "cad_replacement.*",
            "ros_nodes",
            "ros_nodes.*",
        ]
        ),
        "recon_core.default_config",
    ],
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/launch", glob("launch/*.py")),
        (f"share/{PACKAGE}/config", glob("config/*.yaml") + glob("config/*.rviz") + glob("config/*.xml")),
        (f"share/{PACKAGE}/config/segmentation", glob("config/segmentation/*.yaml")),
        (f"share/{PACKAGE}/config/presets", glob("config/presets/*.yaml")),
    ],
    # config/ is installed as the package recon_core.default_config (found through importlib.resources)
    package_dir={"recon_core.default_config": "config"},
    package_data={"recon_core.default_config": ["*.yaml", "*.xml", "segmentation/*.yaml", "presets/*.yaml"]},
    install_requires=["setuptools"],
    zip_safe=False,
    python_requires=">=3.10",
    entry_points={
        "console_scripts": [
            "scene-recon = scene_recon.cli:run_and_exit",
            "rgbd_player = ros_nodes.rgbd_player:main",
            "contact_graph_node = ros_nodes.contact_graph_node:main",
            "cad_replacer = ros_nodes.cad_replacer_node:main",
            "panoptic_mapper = ros_nodes.mapper_node:main",
            "segmentation_service = ros_nodes.segmentation_service:main",
        ],
    },
)
