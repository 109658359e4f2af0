"""Yaskawa MotoROS over TCP (ROS-Industrial simple_message): codec, shared link, driver, fake controller.

Typical use, both arms of one controller sharing its connections::

    link = MotorosLink("192.168.255.1", start_traj_timeout_s=15.0)
    with MotorosDriver(link, group=0, max_speed_rad_s=v1) as r1, MotorosDriver(link, 1, v2) as r2:
        r1.move_to(q, speed_fraction=0.1)
        r1.wait_settled(timeout_s=30.0)
"""

from drivers.errors import InvalidArgument
from drivers.motoros.driver import MotorosDriver, to_robot_status
from drivers.motoros.errors import ControllerNotReady, NonFiniteFeedback
from drivers.motoros.fake import FakeMotorosController
from drivers.motoros.fake_cell import build_fake_controller, run_fake_controller, serve_fake_controller
from drivers.motoros.framing import Framer
from drivers.motoros.link import MOTION_PORT, STATE_PORT, MotorosLink

__all__ = ["ControllerNotReady", "FakeMotorosController", "Framer", "InvalidArgument", "MOTION_PORT",
           "MotorosDriver", "MotorosLink", "NonFiniteFeedback", "STATE_PORT", "build_fake_controller",
           "run_fake_controller", "serve_fake_controller", "to_robot_status"]
