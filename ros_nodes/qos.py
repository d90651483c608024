"""QoS profiles used by the nodes (one place, so publishers and subscribers agree)."""

from __future__ import annotations

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

#: Camera streams: RELIABLE measured 30 Hz at 13 ms across processes; BEST_EFFORT lost a third of
#: 640x480 frames (REFERENCE.md). A short queue bounds latency.
SENSOR_RELIABLE = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5, reliability=ReliabilityPolicy.RELIABLE)

#: The same for publishers that offer best effort only (`ros_nodes.sensor_subscription` picks).
SENSOR_BEST_EFFORT = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5, reliability=ReliabilityPolicy.BEST_EFFORT)

#: A played recording: every frame must arrive (the ROS graph must map what `scene-recon run` maps), and
#: on loaded cores a reliable KEEP_LAST(5) writer or reader overwrote frames not yet taken (2 of 60
#: 320x240 frames lost). A deeper history on both sides absorbs a consumer that falls behind for a moment.
RECORDING_DEPTH = 30
SENSOR_RECORDING = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=RECORDING_DEPTH,
                              reliability=ReliabilityPolicy.RELIABLE)

#: /tf_static is latched: late joiners must still receive it.
TF_STATIC = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.TRANSIENT_LOCAL)

#: Latched outputs (the contact graph, its markers): a late subscriber gets the last one.
LATCHED = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)

#: The mapper's entity snapshots (each holds every entity): only the newest matters, but it must
#: arrive, also to a consumer started (or restarted) after it was published: transient-local.
#: (A transient-local subscriber matches transient-local publishers only; a volatile one matches both.)
#: Depth 2 as before: a consumer that falls one snapshot behind still sees its `removed_ids`.
ENTITIES = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=2, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)

#: Status reports (the mapper's counters): the newest, also for a late `ros2 topic echo`.
STATUS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                    durability=DurabilityPolicy.TRANSIENT_LOCAL)

TF_DYNAMIC = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.RELIABLE)

#: What our TF listener subscribes with: best effort matches reliable and best-effort publishers
#: alike, and a reliable reader stalled here (only the first samples of a replayed /tf arrived
#: while the image streams flowed, with no message-lost event); poses are interpolated anyway.
TF_LISTEN = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.BEST_EFFORT)

#: The same, reliable, for a played recording (the mapper's `tf_reliable`): a best-effort reader loses for
#: good the /tf samples sent before it has matched the player's writer (the player only sees its writer
#: match the reader): on a loaded machine the first 6 frames' poses of a bag were lost even after the
#: player's 1.5 s grace, and the frame just before the first sample took that sample's pose (a map unlike
#: `scene-recon run`'s). A reliable reader matches reliable publishers only (the player's /tf is). Such a
#: reader recovers what it missed from the writer's history, so the player stays until every reliable
#: subscriber has acknowledged (`drain_timeout_s`): leaving 0.5 s after its last frame, it took the last 8
#: poses with it once (maybe the "stall" noted above).
TF_LISTEN_RELIABLE = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.RELIABLE)

#: The mapper's back-pressure topic (std_msgs/String, JSON; STATUS QoS): which played frames it has still
#: to do. `rgbd_player` paces a recording by it (pace_topic), so a slow mapper is never outrun.
PROGRESS_TOPIC = "mapper_progress"
