"""Tests of the bridge's ros2 backend without ROS 2: its decisions (goal status, arrival,
limits from a URDF) as functions, and `Ros2Backend.move` against a fake of the rclpy API
surface it uses (action client, joint-state subscription, clock, parameters), so that a
cancelled goal with error code 0, a success whose joint states are off target and the goal's
tolerances are checked. Run: python3 -m unittest deploy/ros2/test_calibd_joint_bridge.py
(drivers/tests/joints_bridge.rs runs it under cargo test)."""

import asyncio
import importlib.util
import math
import os
import sys
import time
import types
import unittest

HERE = os.path.dirname(os.path.abspath(__file__))
TALOS_URDF = os.path.join(HERE, "..", "..", "tests", "data", "robots", "talos", "talos_reduced.urdf")


class Fake:
    """What the fake ROS graph does with a goal: the goal status and error code the action
    server returns, and the offset of the joint states published after it (None: none)."""

    status = 4
    error_code = 0
    state_offset = 0.0
    q = {}
    urdf = None
    goals = []
    node = None
    joint_cb = None


def _module(name, **attrs):
    m = types.ModuleType(name)
    m.__dict__.update(attrs)
    sys.modules[name] = m
    return m


class Future:
    def __init__(self):
        self._v, self._done, self._cbs = None, False, []

    def set_result(self, v):
        self._v, self._done = v, True
        for cb in self._cbs:
            cb(self)

    def add_done_callback(self, cb):
        if self._done:
            cb(self)
        else:
            self._cbs.append(cb)

    def result(self):
        return self._v

    def exception(self):
        return None


def done(v):
    f = Future()
    f.set_result(v)
    return f


class Msg:
    def __init__(self, **kw):
        self.__dict__.update(kw)


class JointState(Msg):
    pass


class String(Msg):
    pass


class Goal:
    def __init__(self):
        self.trajectory = Msg(joint_names=[], points=[])
        self.goal_tolerance = []
        self.goal_time_tolerance = None


class GoalHandle:
    accepted = True

    def __init__(self, goal):
        self.goal = goal

    def get_result_async(self):
        # The robot "moves": the streamed joint states now show target + offset.
        names = list(self.goal.trajectory.joint_names)
        pos = [p + Fake.state_offset for p in self.goal.trajectory.points[0].positions]
        Fake.q.update(zip(names, pos))
        return done(Msg(status=Fake.status, result=Msg(error_code=Fake.error_code, error_string="")))

    def cancel_goal_async(self):
        return done(Msg())


class ActionClient:
    def __init__(self, node, kind, name):
        self.name = name

    def server_is_ready(self):
        return True

    def send_goal_async(self, goal):
        Fake.goals.append(goal)
        return done(GoalHandle(goal))


class Node:
    def __init__(self, name, parameter_overrides=()):
        self.params = {p.name: p.value for p in parameter_overrides}
        Fake.node = self

    def create_subscription(self, kind, topic, cb, qos):
        if kind is JointState:
            Fake.joint_cb = cb
        elif kind is String and Fake.urdf is not None:
            cb(String(data=Fake.urdf))
        return (kind, topic)

    def destroy_subscription(self, sub):
        pass

    def get_clock(self):
        return Msg(now=self._now)

    def _now(self):
        # /joint_states streams: every look at the clock sees one more message.
        if Fake.joint_cb is not None:
            Fake.joint_cb(JointState(name=list(Fake.q), position=list(Fake.q.values())))
        return Msg(nanoseconds=time.monotonic_ns())


class Parameter:
    class Type:
        BOOL = "bool"

    def __init__(self, name, kind, value):
        self.name, self.kind, self.value = name, kind, value


class Executor:
    def add_node(self, node):
        pass

    def spin(self):
        pass


def install_fake_ros():
    _module("rclpy", init=lambda args=None: None)
    _module("rclpy.action", ActionClient=ActionClient)
    _module("rclpy.executors", MultiThreadedExecutor=Executor)
    _module("rclpy.node", Node=Node)
    _module("rclpy.parameter", Parameter=Parameter)
    _module("rclpy.qos", QoSProfile=Msg, DurabilityPolicy=Msg(TRANSIENT_LOCAL="transient_local"))
    _module("control_msgs")
    _module("control_msgs.action", FollowJointTrajectory=Msg(Goal=Goal))
    _module("control_msgs.msg", JointTolerance=Msg)
    _module("sensor_msgs")
    _module("sensor_msgs.msg", JointState=JointState)
    _module("std_msgs")
    _module("std_msgs.msg", String=String)
    _module("builtin_interfaces")
    _module("builtin_interfaces.msg", Duration=Msg)
    _module("trajectory_msgs")
    _module("trajectory_msgs.msg", JointTrajectoryPoint=Msg)


spec = importlib.util.spec_from_file_location("calibd_joint_bridge", os.path.join(HERE, "calibd_joint_bridge.py"))
bridge = importlib.util.module_from_spec(spec)
spec.loader.exec_module(bridge)

ARM = ["arm_left_1_joint", "arm_left_2_joint"]


class Decisions(unittest.TestCase):
    def test_only_succeeded_with_code_zero_is_success(self):
        bridge.check_goal_result("/arm", 4, 0, "")
        for status, name in ((5, "CANCELED"), (6, "ABORTED"), (0, "UNKNOWN")):
            with self.assertRaises(bridge.JointError) as e:
                bridge.check_goal_result("/arm", status, 0, "")
            self.assertIn(name, e.exception.message)
            self.assertEqual(e.exception.code, "fault")
        with self.assertRaises(bridge.JointError) as e:
            bridge.check_goal_result("/arm", 4, -4, "PATH_TOLERANCE_VIOLATED")
        self.assertIn("-4", e.exception.message)

    def test_off_target_names_missing_and_far_joints(self):
        off = bridge.off_target({"a": 1.0, "b": 0.0, "c": 0.5}, {"a": 1.001, "b": 0.01}, 0.002)
        self.assertEqual([n for n, _ in off], ["b", "c"])
        self.assertAlmostEqual(off[0][1], 0.01)
        self.assertIsNone(off[1][1])

    def test_limits_from_the_talos_urdf_and_merged_with_given_ones(self):
        with open(TALOS_URDF, encoding="utf-8") as f:
            urdf = f.read()
        lim = bridge.limits_from_urdf(urdf, ARM)
        # The values the README's --limits line copies from the same file.
        self.assertAlmostEqual(lim[0][0], -1.5708, places=4)
        self.assertAlmostEqual(lim[0][1], 0.5236, places=4)
        self.assertAlmostEqual(lim[1][0], 0.0, places=4)
        self.assertAlmostEqual(lim[1][1], 2.8798, places=4)
        merged = bridge.merge_limits(ARM, [(-1.0, 2.0), (-1.0, 1.0)], lim)
        self.assertEqual(merged[0], (-1.0, lim[0][1]))
        self.assertEqual(merged[1], (lim[1][0], 1.0))
        with self.assertRaises(SystemExit):
            bridge.merge_limits(ARM, [(1.0, 2.0), (0.0, 1.0)], lim)
        with self.assertRaises(ValueError) as e:
            bridge.limits_from_urdf(urdf, ["no_such_joint"])
        self.assertIn("no_such_joint", str(e.exception))
        cont = '<robot name="r"><joint name="w" type="continuous"/></robot>'
        self.assertEqual(bridge.limits_from_urdf(cont, ["w"]), [(-2 * math.pi, 2 * math.pi)])


class Ros2BackendOnFakeRos(unittest.TestCase):
    def setUp(self):
        install_fake_ros()
        Fake.status, Fake.error_code, Fake.state_offset, Fake.goals = 4, 0, 0.0, []
        Fake.q = {"arm_left_1_joint": 0.0, "arm_left_2_joint": 0.5}
        Fake.urdf = None

    def backend(self, **kw):
        o = bridge.Ros2Options(goal_tolerance_rad=0.002, goal_time_tolerance_s=0.3, **kw)
        b = bridge.Ros2Backend("talos", ARM, kw.get("limits", [(-1, 1), (0, 2)]) if not kw.get("robot_description_topic") else None,
                               [("/arm_left_controller", None)], "/joint_states", o)
        Fake.joint_cb(JointState(name=list(Fake.q), position=list(Fake.q.values())))
        return b

    def move(self, b, target):
        return asyncio.run(b.move(target, 1.5))

    def test_a_succeeded_goal_confirmed_by_the_joint_states_returns_them(self):
        b = self.backend()
        got = self.move(b, {"arm_left_1_joint": 0.25, "arm_left_2_joint": 1.0})
        self.assertEqual(got, {"arm_left_1_joint": 0.25, "arm_left_2_joint": 1.0})
        goal = Fake.goals[0]
        self.assertEqual([(t.name, t.position) for t in goal.goal_tolerance], [(n, 0.002) for n in ARM])
        self.assertEqual((goal.goal_time_tolerance.sec, goal.goal_time_tolerance.nanosec), (0, 300_000_000))
        self.assertEqual(goal.trajectory.points[0].time_from_start.sec, 1)
        self.assertFalse(Fake.node.params["use_sim_time"])

    def test_a_cancelled_goal_with_error_code_zero_is_a_fault(self):
        b = self.backend()
        Fake.status = 5
        with self.assertRaises(bridge.JointError) as e:
            self.move(b, {"arm_left_1_joint": 0.25, "arm_left_2_joint": 1.0})
        self.assertIn("CANCELED", e.exception.message)

    def test_success_with_joint_states_off_target_is_a_fault_naming_the_joints(self):
        b = self.backend()
        Fake.state_offset = 0.01
        with self.assertRaises(bridge.JointError) as e:
            self.move(b, {"arm_left_1_joint": 0.25, "arm_left_2_joint": 1.0})
        self.assertIn("off target", e.exception.message)
        self.assertIn("arm_left_1_joint +0.01000 rad", e.exception.message)

    def test_sim_time_and_limits_from_robot_description(self):
        with open(TALOS_URDF, encoding="utf-8") as f:
            Fake.urdf = f.read()
        b = self.backend(use_sim_time=True, robot_description_topic="/robot_description")
        self.assertTrue(Fake.node.params["use_sim_time"])
        self.assertAlmostEqual(b.limits[0][0], -1.5708, places=4)
        self.assertAlmostEqual(b.limits[1][1], 2.8798, places=4)


if __name__ == "__main__":
    unittest.main()
