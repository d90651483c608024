"""ROS 2 adapter layer: message conversion, parameters, QoS, timers and services around the
ROS-free core packages. Nothing algorithmic lives here."""
