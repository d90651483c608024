"""One way to run a node: environment, init, spin until Ctrl-C / SIGTERM, clean shutdown."""

from __future__ import annotations

import signal
from collections.abc import Callable

import rclpy
from rclpy.executors import Executor, ExternalShutdownException
from rclpy.node import Node

from recon_core.ros_env import ensure_ros_environment


def install_sigterm_handler() -> None:
    """SIGTERM shuts rclpy down like Ctrl-C does: spinning ends and the node's clean-up runs (exit 0)."""
    signal.signal(signal.SIGTERM, lambda *_: rclpy.try_shutdown())


def run_node(factory: Callable[[], Node], args: list[str] | None = None, threads: int = 1) -> int:
    """Create the node with `factory` and spin it (on `threads` executor threads); returns the exit code.

    On Ctrl-C or SIGTERM the executor stops, then the node's `on_shutdown()` (if it has one: the
    mapper's last checkpoint) runs before the node is destroyed.
    """
    ensure_ros_environment()
    rclpy.init(args=args)
    install_sigterm_handler()
    node = factory()
    executor: Executor | None = None
    try:
        if threads > 1:
            from rclpy.executors import MultiThreadedExecutor

            executor = MultiThreadedExecutor(num_threads=threads)
            executor.add_node(node)
            executor.spin()
        else:
            rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if executor is not None:
            executor.shutdown(timeout_sec=30)  # callbacks still running finish first
        hook = getattr(node, "on_shutdown", None)
        if hook is not None:
            try:
                hook()
            except Exception as exc:  # a failing clean-up is reported, the exit stays orderly
                node.get_logger().error(f"shutdown: {type(exc).__name__}: {exc}")
        node.destroy_node()
        rclpy.try_shutdown()
    return 0
