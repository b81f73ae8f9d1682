#!/usr/bin/env python3
"""calibd joint bridge: serves calibd's joint-interface protocol `calibd-joints/1` on a TCP
port and forwards it to a robot.

The protocol (documented in calibd's `drivers/src/joints/mod.rs`): JSON lines over TCP, one
object per LF-terminated line of at most 64 KiB, one reply per request, in order.

    {"op":"hello"} -> {"ok":true,"protocol":"calibd-joints/1","robot":..,"joints":[..],"limits_rad":[[lo,hi],..]}
    {"op":"read"}  -> {"ok":true,"positions_rad":{name: rad},"moving":bool}
    {"op":"move","positions_rad":{name: rad},"duration_s":s} -> {"ok":true,"positions_rad":{..}} once reached
    {"op":"stop"}  -> {"ok":true}
    errors: {"ok":false,"error":{"code":"unknown_joint|out_of_limits|busy|fault|bad_request","message":..}}

A `stop` takes effect as soon as it is read (the move it halts fails with `fault`); other
requests that arrive while a move runs are answered after it, in order. One move at a time
across connections (`busy` otherwise).

Backends:
  fake  in-memory joints that move linearly over each move's duration (tests, trying it out).
  ros2  a `control_msgs/action/FollowJointTrajectory` client per `--controller` for moves
        (one goal per controller, same duration, with goal tolerances and a goal time
        tolerance) and a `sensor_msgs/JointState` subscription (`--joint-states`) for
        positions. A move succeeds only when every goal's *status* is SUCCEEDED with error
        code 0 (a cancelled or aborted goal also carries error code 0) and the joint states
        then show every joint within the goal tolerance. Limits come from the URDF
        (`--urdf FILE` or the `robot_description` topic) when given; `--use-sim-time` runs
        the node on /clock. `rclpy` is imported only for this backend.

The protocol half uses the Python standard library only (asyncio).
"""

import argparse
import asyncio
import json
import logging
import math
import sys
import threading

PROTOCOL = "calibd-joints/1"
MAX_LINE = 64 * 1024
TICK_S = 0.005

log = logging.getLogger("calibd_joint_bridge")


class JointError(Exception):
    """A request that fails with a protocol error code."""

    def __init__(self, code, message):
        super().__init__(message)
        self.code = code
        self.message = message


class Stopped(JointError):
    """A move halted by `stop`."""

    def __init__(self, where):
        super().__init__("fault", "stopped before the posture was reached, at " + where)


def fmt_positions(positions):
    return ", ".join("%s = %.4f" % (k, v) for k, v in positions.items())


# action_msgs/msg/GoalStatus codes.
GOAL_STATUS = {
    0: "UNKNOWN",
    1: "ACCEPTED",
    2: "EXECUTING",
    3: "CANCELING",
    4: "SUCCEEDED",
    5: "CANCELED",
    6: "ABORTED",
}
STATUS_SUCCEEDED = 4


def check_goal_result(action, status, error_code, error_string):
    """Raise JointError('fault') unless the goal SUCCEEDED with error code 0: a goal that was
    cancelled, pre-empted or aborted can still carry error code 0 (SUCCESSFUL)."""
    if status != STATUS_SUCCEEDED:
        raise JointError(
            "fault",
            "%s ended %s (error %d%s)"
            % (action, GOAL_STATUS.get(status, "status %d" % status), error_code,
               (" " + error_string) if error_string else ""),
        )
    if error_code != 0:
        raise JointError("fault", "%s failed: error %d %s" % (action, error_code, error_string))


def off_target(target, positions, tolerance_rad):
    """Joints of `target` whose measured position is missing or further than the tolerance,
    as [(joint, error_rad or None)]."""
    out = []
    for name, want in target.items():
        have = positions.get(name)
        if have is None:
            out.append((name, None))
        elif abs(have - want) > tolerance_rad:
            out.append((name, have - want))
    return out


def limits_from_urdf(xml_text, names):
    """[(lo, hi)] in radians (or metres) for `names` from a URDF's <joint><limit>; a
    continuous joint gets [-2 pi, 2 pi]. Raises ValueError naming what is missing."""
    import xml.etree.ElementTree as ET

    try:
        root = ET.fromstring(xml_text)
    except ET.ParseError as e:
        raise ValueError("robot_description is not XML: %s" % e)
    # Only the robot's own <joint> elements: <transmission> has <joint> children too.
    joints = {j.get("name"): j for j in root.findall("joint")}
    out = []
    for n in names:
        j = joints.get(n)
        if j is None:
            raise ValueError("robot_description has no joint %r" % n)
        kind = j.get("type")
        if kind == "continuous":
            # No limit; offered to calibd as one turn each way (hello's limits are finite).
            out.append((-2.0 * math.pi, 2.0 * math.pi))
            continue
        if kind not in ("revolute", "prismatic"):
            raise ValueError("joint %r is %s, not a revolute, prismatic or continuous joint" % (n, kind))
        lim = j.find("limit")
        if lim is None or lim.get("lower") is None or lim.get("upper") is None:
            raise ValueError("joint %r has no <limit lower=.. upper=..>" % n)
        lo, hi = float(lim.get("lower")), float(lim.get("upper"))
        if not lo <= hi:
            raise ValueError("joint %r: lower %s > upper %s" % (n, lo, hi))
        out.append((lo, hi))
    return out


def merge_limits(names, given, urdf):
    """The limits to enforce: the URDF's, narrowed by the ones given on the command line
    (never widened beyond the URDF); raises SystemExit if they do not overlap."""
    if urdf is None:
        return given
    if given is None:
        return urdf
    out = []
    for n, (glo, ghi), (ulo, uhi) in zip(names, given, urdf):
        lo, hi = max(glo, ulo), min(ghi, uhi)
        if lo > hi:
            raise SystemExit("--limits for %s [%s, %s] lie outside the URDF's [%s, %s]" % (n, glo, ghi, ulo, uhi))
        out.append((lo, hi))
    return out


class FakeBackend:
    """Joints in memory, moving linearly over a move's duration."""

    def __init__(self, robot, names, limits):
        self.robot = robot
        self.names = list(names)
        self.limits = list(limits)
        self.q = {n: min(max(0.0, lo), hi) for n, (lo, hi) in zip(self.names, self.limits)}
        self.moving = False
        self._stops = 0

    async def positions(self):
        return dict(self.q)

    async def move(self, target, duration_s):
        """Go to `target` (every joint) in `duration_s`; raises Stopped when stopped."""
        start = dict(self.q)
        stops = self._stops
        loop = asyncio.get_running_loop()
        t0 = loop.time()
        while True:
            if self._stops != stops:
                raise Stopped(fmt_positions(self.q))
            t = loop.time() - t0
            if t >= duration_s:
                self.q = dict(target)
                return dict(self.q)
            u = t / duration_s
            self.q = {n: start[n] + u * (target[n] - start[n]) for n in self.names}
            await asyncio.sleep(TICK_S)

    async def stop(self):
        self._stops += 1


class Ros2Options:
    """Settings of the ros2 backend (command line)."""

    def __init__(self, goal_tolerance_rad=0.002, goal_time_tolerance_s=1.0, use_sim_time=False,
                 robot_description_topic=None, wait_s=10.0):
        self.goal_tolerance_rad = goal_tolerance_rad
        self.goal_time_tolerance_s = goal_time_tolerance_s
        self.use_sim_time = use_sim_time
        self.robot_description_topic = robot_description_topic
        self.wait_s = wait_s


class Ros2Backend:
    """A ROS 2 robot: one FollowJointTrajectory action client per trajectory controller for
    moves (a move sends one goal to each controller, all with the same duration), and a
    JointState subscription for positions."""

    def __init__(self, robot, names, limits, controllers, joint_states, options=None):
        # Imported here so that the fake backend runs without ROS 2.
        import rclpy
        from rclpy.action import ActionClient
        from rclpy.executors import MultiThreadedExecutor
        from rclpy.node import Node
        from rclpy.parameter import Parameter
        from control_msgs.action import FollowJointTrajectory
        from sensor_msgs.msg import JointState

        o = options or Ros2Options()
        self.robot = robot
        self.names = list(names)
        self.limits = list(limits) if limits is not None else None
        self.moving = False
        self.options = o
        self._FollowJointTrajectory = FollowJointTrajectory
        self._lock = threading.Lock()
        self._q = {}
        self._states = 0  # JointState messages received
        self._goals = []
        self._stops = 0
        rclpy.init(args=None)
        self._node = Node(
            "calibd_joint_bridge",
            parameter_overrides=[Parameter("use_sim_time", Parameter.Type.BOOL, bool(o.use_sim_time))],
        )
        # controllers: [(name, [joints])]; joints None = every joint of the bridge.
        self._controllers = []
        for name, joints in controllers:
            action = name.rstrip("/") + "/follow_joint_trajectory"
            client = ActionClient(self._node, FollowJointTrajectory, action)
            self._controllers.append((action, client, joints or list(self.names)))
            log.info("ros2 backend: action %s for %s", action, ", ".join(joints or self.names))
        self._node.create_subscription(JointState, joint_states, self._on_joint_state, 10)
        self._executor = MultiThreadedExecutor()
        self._executor.add_node(self._node)
        threading.Thread(target=self._executor.spin, daemon=True).start()
        log.info("ros2 backend: joint states on %s", joint_states)
        if o.robot_description_topic:
            urdf = self._robot_description(o.robot_description_topic, o.wait_s)
            self.limits = merge_limits(self.names, self.limits, limits_from_urdf(urdf, self.names))
            log.info("ros2 backend: limits from %s", o.robot_description_topic)
        if self.limits is None:
            raise SystemExit("no joint limits: give --limits, --urdf or --robot-description")

    def _robot_description(self, topic, wait_s):
        """The URDF text latched on `topic` (robot_state_publisher publishes it once, with
        transient-local durability, so a late subscriber still gets it)."""
        from rclpy.qos import DurabilityPolicy, QoSProfile
        from std_msgs.msg import String

        got = threading.Event()
        text = []

        def on_msg(msg):
            if not got.is_set():
                text.append(msg.data)
                got.set()

        qos = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        sub = self._node.create_subscription(String, topic, on_msg, qos)
        try:
            if not got.wait(wait_s):
                raise SystemExit("no URDF on %s within %.0f s" % (topic, wait_s))
        finally:
            self._node.destroy_subscription(sub)
        return text[0]

    def _on_joint_state(self, msg):
        with self._lock:
            for n, p in zip(msg.name, msg.position):
                self._q[n] = float(p)
            self._states += 1

    def _now_s(self):
        """The node's clock in seconds: simulation time under --use-sim-time."""
        return self._node.get_clock().now().nanoseconds * 1e-9

    async def _confirm_arrival(self, target):
        """Wait (node clock) until a joint state received after the goals finished shows
        every joint within the goal tolerance; JointError('fault') naming the joints that
        are off once the goal time tolerance has passed."""
        o = self.options
        with self._lock:
            seen = self._states
        deadline = self._now_s() + o.goal_time_tolerance_s
        while True:
            with self._lock:
                fresh = self._states > seen
                q = dict(self._q)
            off = off_target(target, q, o.goal_tolerance_rad) if fresh else None
            if off == []:
                return
            if self._now_s() > deadline:
                if off is None:
                    raise JointError("fault", "no joint state arrived after the move")
                raise JointError(
                    "fault",
                    "the controllers reported success but the joint states are off target: "
                    + ", ".join(
                        "%s %s" % (n, "missing" if e is None else "%+.5f rad" % e) for n, e in off
                    ),
                )
            await asyncio.sleep(TICK_S)

    async def _await(self, rclpy_future):
        """An rclpy future (completed on the executor thread) as an asyncio awaitable."""
        loop = asyncio.get_running_loop()
        done = loop.create_future()

        def finish(f):
            def set_result():
                if done.done():
                    return
                exc = f.exception()
                if exc is not None:
                    done.set_exception(exc)
                else:
                    done.set_result(f.result())

            loop.call_soon_threadsafe(set_result)

        rclpy_future.add_done_callback(finish)
        return await done

    async def positions(self):
        with self._lock:
            missing = [n for n in self.names if n not in self._q]
            if missing:
                raise JointError("fault", "no joint state yet for " + ", ".join(missing))
            return {n: self._q[n] for n in self.names}

    async def _follow(self, action, client, joints, target, duration_s, stops):
        from builtin_interfaces.msg import Duration
        from trajectory_msgs.msg import JointTrajectoryPoint

        if not client.server_is_ready():
            ready = await asyncio.get_running_loop().run_in_executor(
                None, lambda: client.wait_for_server(timeout_sec=2.0)
            )
            if not ready:
                raise JointError("fault", "action server %s is not available" % action)
        goal = self._FollowJointTrajectory.Goal()
        goal.trajectory.joint_names = list(joints)
        point = JointTrajectoryPoint()
        point.positions = [float(target[n]) for n in joints]
        point.velocities = [0.0] * len(joints)
        secs = int(duration_s)
        point.time_from_start = Duration(sec=secs, nanosec=int((duration_s - secs) * 1e9))
        goal.trajectory.points = [point]
        from control_msgs.msg import JointTolerance

        o = self.options
        goal.goal_tolerance = [JointTolerance(name=n, position=o.goal_tolerance_rad) for n in joints]
        gt = o.goal_time_tolerance_s
        goal.goal_time_tolerance = Duration(sec=int(gt), nanosec=int((gt - int(gt)) * 1e9))
        handle = await self._await(client.send_goal_async(goal))
        if not handle.accepted:
            raise JointError("fault", "%s rejected the goal" % action)
        self._goals.append(handle)
        try:
            if self._stops != stops:
                await self._await(handle.cancel_goal_async())
            wrapped = await self._await(handle.get_result_async())
        finally:
            self._goals.remove(handle)
        if self._stops == stops:
            check_goal_result(action, wrapped.status, wrapped.result.error_code, wrapped.result.error_string)

    async def move(self, target, duration_s):
        stops = self._stops
        results = await asyncio.gather(
            *(
                self._follow(action, client, joints, target, duration_s, stops)
                for action, client, joints in self._controllers
            ),
            return_exceptions=True,
        )
        if self._stops != stops:
            raise Stopped(fmt_positions(await self.positions()))
        for r in results:
            if isinstance(r, BaseException):
                await self.stop()  # the other controllers must not go on alone
                raise r
        await self._confirm_arrival(target)
        return await self.positions()

    async def stop(self):
        self._stops += 1
        for goal in list(self._goals):
            await self._await(goal.cancel_goal_async())


class Bridge:
    """The protocol over a backend; one move at a time across connections."""

    def __init__(self, backend):
        self.backend = backend
        self.busy = False

    def hello(self):
        return {
            "ok": True,
            "protocol": PROTOCOL,
            "robot": self.backend.robot,
            "joints": self.backend.names,
            "limits_rad": [[lo, hi] for lo, hi in self.backend.limits],
        }

    async def read(self):
        return {
            "ok": True,
            "positions_rad": await self.backend.positions(),
            "moving": self.busy,
        }

    async def move(self, positions, duration_s):
        limits = dict(zip(self.backend.names, self.backend.limits))
        for name, v in positions.items():
            if name not in limits:
                raise JointError(
                    "unknown_joint",
                    "no joint %r (joints: %s)" % (name[:64], ", ".join(self.backend.names)),
                )
            lo, hi = limits[name]
            if not lo <= v <= hi:
                raise JointError("out_of_limits", "%s = %s rad is outside [%s, %s]" % (name, v, lo, hi))
        if self.busy:
            raise JointError("busy", "another move is running")
        self.busy = True
        self.backend.moving = True
        try:
            target = await self.backend.positions()
            target.update(positions)
            log.info("move: %d joints in %.3f s", len(positions), duration_s)
            reached = await self.backend.move(target, duration_s)
            return {"ok": True, "positions_rad": reached}
        finally:
            self.busy = False
            self.backend.moving = False

    async def stop(self):
        await self.backend.stop()
        return {"ok": True}


def _no_constants(token):
    raise ValueError("%s is not a JSON number" % token)


def parse_request(line):
    """A request line as (op, args); raises JointError('bad_request', ...)."""
    try:
        text = line.decode("utf-8")
    except UnicodeDecodeError:
        raise JointError("bad_request", "line is not UTF-8")
    try:
        req = json.loads(text, parse_constant=_no_constants)
    except ValueError as e:
        raise JointError("bad_request", "not a JSON object: %s" % e)
    if not isinstance(req, dict) or not isinstance(req.get("op"), str):
        raise JointError("bad_request", 'a request is an object with a string "op"')
    op = req["op"]
    if op in ("hello", "read", "stop"):
        return op, None
    if op != "move":
        raise JointError("bad_request", "unknown op %r (expected hello, read, move or stop)" % op[:32])
    positions = req.get("positions_rad")
    duration = req.get("duration_s")
    if not isinstance(positions, dict):
        raise JointError("bad_request", "bad move request: positions_rad is not an object")
    for k, v in positions.items():
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise JointError("bad_request", "bad move request: position of %r is not a number" % k[:64])
    if isinstance(duration, bool) or not isinstance(duration, (int, float)) or not (
        math.isfinite(duration) and duration >= 0
    ):
        raise JointError("bad_request", "duration_s = %r is not a finite number >= 0" % (duration,))
    return op, ({k: float(v) for k, v in positions.items()}, float(duration))


async def read_lines(reader):
    """Yield request lines (bytes, without end of line); an over-long line yields None once
    and is skipped up to its LF."""
    buf = b""
    discarding = False
    while True:
        lf = buf.find(b"\n")
        if lf < 0:
            if len(buf) >= MAX_LINE:
                buf = b""
                if not discarding:
                    discarding = True
                    yield None
            chunk = await reader.read(65536)
            if not chunk:
                return
            buf += chunk
            continue
        line, buf = buf[:lf], buf[lf + 1 :]
        if discarding:
            discarding = False
            continue
        if len(line) + 1 > MAX_LINE:
            yield None
            continue
        if line.endswith(b"\r"):
            line = line[:-1]
        if line.strip():
            yield line


def encode(reply):
    return (json.dumps(reply, separators=(",", ":"), allow_nan=False) + "\n").encode()


def error(code, message):
    return {"ok": False, "error": {"code": code, "message": message}}


async def serve_connection(bridge, reader, writer):
    peer = writer.get_extra_info("peername")
    log.info("client %s connected", peer)
    queue = asyncio.Queue()
    moving = [False]  # a move of this connection runs

    async def reading():
        try:
            async for line in read_lines(reader):
                if line is None:
                    await queue.put(JointError("bad_request", "line longer than %d bytes" % MAX_LINE))
                    continue
                try:
                    op, args = parse_request(line)
                except JointError as e:
                    await queue.put(e)
                    continue
                if op == "stop":
                    # A stop acts at once; its reply keeps its place in the order.
                    await bridge.backend.stop()
                await queue.put((op, args))
        except ConnectionError:
            pass
        finally:
            if moving[0]:
                # The client left mid-move: the robot stays where it got to.
                log.warning("client %s left during a move: stopping", peer)
                await bridge.backend.stop()
            await queue.put(None)

    reader_task = asyncio.create_task(reading())
    try:
        while True:
            item = await queue.get()
            if item is None:
                break
            if isinstance(item, JointError):
                reply = error(item.code, item.message)
            else:
                op, args = item
                try:
                    if op == "hello":
                        reply = bridge.hello()
                    elif op == "read":
                        reply = await bridge.read()
                    elif op == "stop":
                        reply = {"ok": True}
                    else:
                        moving[0] = True
                        try:
                            reply = await bridge.move(*args)
                        finally:
                            moving[0] = False
                except JointError as e:
                    reply = error(e.code, e.message)
                except Exception as e:  # a backend failure is the robot's fault, not ours
                    log.exception("backend failed")
                    reply = error("fault", "backend error: %s" % e)
            writer.write(encode(reply))
            await writer.drain()
    except (ConnectionError, asyncio.IncompleteReadError):
        pass
    finally:
        reader_task.cancel()
        writer.close()
        log.info("client %s gone", peer)


def parse_listen(s):
    host, sep, port = s.rpartition(":")
    if not sep or not host:
        raise argparse.ArgumentTypeError("expected HOST:PORT, got %r" % s)
    try:
        return host.strip("[]"), int(port)
    except ValueError:
        raise argparse.ArgumentTypeError("port of %r is not a number" % s)


def parse_limits(s, n):
    """[(lo, hi)] from --limits, or None when not given."""
    if s is None:
        return None
    out = []
    for item in s.split(","):
        lo, sep, hi = item.partition(":")
        try:
            lo, hi = float(lo), float(hi)
        except ValueError:
            raise SystemExit("--limits: %r is not LO:HI" % item)
        if not sep or not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
            raise SystemExit("--limits: %r is not LO:HI with LO <= HI" % item)
        out.append((lo, hi))
    if len(out) != n:
        raise SystemExit("--limits: %d limits for %d joints" % (len(out), n))
    return out


def parse_controllers(specs, names):
    """[(controller, joints or None)] from the --controller values; every joint on exactly one."""
    specs = specs or ["/arm_left_controller"]
    out = []
    for spec in specs:
        name, sep, joints = spec.partition("=")
        out.append((name, [j.strip() for j in joints.split(",") if j.strip()] if sep else None))
    if len(out) == 1 and out[0][1] is None:
        return out
    if any(j is None for _, j in out):
        raise SystemExit("--controller: with several controllers, give each one's joints (NAME=J1,J2)")
    assigned = [j for _, js in out for j in js]
    if sorted(assigned) != sorted(names):
        raise SystemExit("--controller: the controllers' joints must be --joints, each once")
    return out


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--listen", type=parse_listen, default="127.0.0.1:7010", help="HOST:PORT (port 0 picks one)")
    p.add_argument("--backend", choices=["fake", "ros2"], default="fake")
    p.add_argument("--joints", required=True, help="comma-separated joint names, in the robot's order")
    p.add_argument(
        "--limits",
        help="comma-separated LO:HI (rad) per joint, e.g. --limits=-1.57:0.79,0:2.88 "
        "(default: -pi:pi each)",
    )
    p.add_argument("--robot", default=None, help="robot name in hello (default: talos for ros2, fake)")
    p.add_argument(
        "--controller",
        action="append",
        default=None,
        metavar="NAME[=JOINT,JOINT,..]",
        help="ros2: a joint trajectory controller (its FollowJointTrajectory action is "
        "NAME/follow_joint_trajectory) and the joints it drives; repeat for joints on several "
        "controllers; a single NAME alone drives every joint (default /arm_left_controller)",
    )
    p.add_argument("--joint-states", default="/joint_states", help="ros2: JointState topic")
    p.add_argument(
        "--urdf",
        metavar="FILE",
        help="take the joint limits from this URDF (narrowed by --limits when both are given)",
    )
    p.add_argument(
        "--robot-description",
        metavar="TOPIC",
        help="ros2: take the joint limits from the URDF latched on TOPIC (e.g. /robot_description)",
    )
    p.add_argument(
        "--goal-tolerance-rad",
        type=float,
        default=0.002,
        help="ros2: per-joint goal tolerance sent with each goal and checked on the joint states (default 0.002)",
    )
    p.add_argument(
        "--goal-time-tolerance-s",
        type=float,
        default=1.0,
        help="ros2: how late the goal may be reached, and how long to wait for the joint states to confirm it (default 1)",
    )
    p.add_argument("--use-sim-time", action="store_true", help="ros2: run the node on /clock (simulation)")
    p.add_argument("-v", "--verbose", action="store_true")
    a = p.parse_args(argv)
    if isinstance(a.listen, str):
        a.listen = parse_listen(a.listen)
    logging.basicConfig(
        level=logging.INFO if a.verbose else logging.WARNING,
        stream=sys.stderr,
        format="%(asctime)s %(name)s %(levelname)s %(message)s",
    )
    names = [n.strip() for n in a.joints.split(",") if n.strip()]
    if not names or len(set(names)) != len(names):
        raise SystemExit("--joints: give distinct, non-empty joint names")
    limits = parse_limits(a.limits, len(names))
    if a.urdf:
        try:
            with open(a.urdf, encoding="utf-8") as f:
                limits = merge_limits(names, limits, limits_from_urdf(f.read(), names))
        except (OSError, ValueError) as e:
            raise SystemExit("--urdf %s: %s" % (a.urdf, e))
    for name, v in (("--goal-tolerance-rad", a.goal_tolerance_rad), ("--goal-time-tolerance-s", a.goal_time_tolerance_s)):
        if not (math.isfinite(v) and v > 0):
            raise SystemExit("%s: %r is not a positive number" % (name, v))
    if a.backend == "fake":
        backend = FakeBackend(a.robot or "fake", names, limits or [(-math.pi, math.pi)] * len(names))
    else:
        options = Ros2Options(
            goal_tolerance_rad=a.goal_tolerance_rad,
            goal_time_tolerance_s=a.goal_time_tolerance_s,
            use_sim_time=a.use_sim_time,
            robot_description_topic=a.robot_description,
        )
        backend = Ros2Backend(
            a.robot or "talos", names, limits, parse_controllers(a.controller, names), a.joint_states, options
        )
    asyncio.run(serve(Bridge(backend), *a.listen))


async def serve(bridge, host, port):
    server = await asyncio.start_server(lambda r, w: serve_connection(bridge, r, w), host, port)
    bound = server.sockets[0].getsockname()
    print("listening on %s:%d" % (bound[0], bound[1]), flush=True)
    async with server:
        await server.serve_forever()


if __name__ == "__main__":
    try:
        main()
    except KeyboardInterrupt:
        pass
