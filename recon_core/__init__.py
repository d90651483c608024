"""Shared core of scene_recon: what every stage agrees on. ROS-free; imports nothing above it.

* ``errors``          the one error hierarchy (input, config, model, storage)
* ``config``          YAML -> dataclass schema loading, dotted names (= ROS parameter names), CONFIG_DIR
* ``classes``         the semantic class table (config/classes.yaml) as data
* ``geometry``        gravity, rigid transforms, the oriented (gravity-aligned) box, planes and RANSAC,
                      2D polygons
* ``frame``           an RGB-D frame with intrinsics and pose (stage 1-2 input)
* ``entity``          a mapped entity (stage 2 output, stage 3-4 input) and its folder format
* ``contact_graph``   the contact graph (stage 3 output, stage 4 input)
* ``kinematic_tree``  a kinematic tree and the one URDF writer (stage 3-4 output)
* ``names``, ``io``   name sanitising for URDF/TF/files; atomic writes
* ``ros_env``         the ament environment of the PyPI ROS wheels (no ROS import)
"""
