"""scene_recon tools: the top layer above the stages (ROS-free).

The `scene-recon` command line (`scene_recon.cli`, `scene_recon.commands`), the synthetic world
used for testing and evaluation (`scene_recon.synthetic`), evaluation against ground truth
(`scene_recon.evaluation`) and entity sources (`scene_recon.sources`). Shared types and the
configuration machinery live in `recon_core`; see docs/ARCHITECTURE.md.
"""

__version__ = "0.1.0"
