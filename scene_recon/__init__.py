"""scene_recon: RGB-D stream to an interactive, kinematic scene.

The umbrella package holds what every stage shares and is ROS-free: the configuration schema
machinery (`scene_recon.config`), the synthetic world used for evaluation (`scene_recon.synthetic`)
and the `scene-recon` command line (`scene_recon.cli`).
"""

__version__ = "0.1.0"
