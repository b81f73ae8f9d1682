"""Conformance: the third-party abb-robot-client 0.4.0 (requests + HTTP Digest) against
calibd's RWS mock of an IRC5 with an IRB 120.

Usage: python abb_rws_check.py HOST PORT
"""
import sys
import time

import numpy as np
from abb_robot_client.rws import RWS


def main(host, port):
    base = f"http://{host}:{port}"
    rws = RWS(base, "Default User", "robotics")
    jt = rws.get_jointtarget()
    assert np.allclose(jt.robax, [0, 0, 0, 0, 30, 0]), jt
    rt = rws.get_robtarget()
    assert np.isclose(np.linalg.norm(rt.rot), 1.0) and rt.trans[2] > 0, rt
    assert rws.get_controller_state() == "motoron"
    assert rws.get_operation_mode() == "AUTO"
    assert rws.get_execution_state().ctrlexecstate == "running"
    # Identity (calibd lab check): abb-robot-client 0.4.0 has no system-info helper, so its
    # own GET path (Digest, cookies, JSON parsing) reads RWS 1.0 /rw/system and the module
    # list of T_ROB1; get_tasks() is its helper for the task list.
    sysinfo = rws._do_get("rw/system")["_embedded"]["_state"][0]
    assert sysinfo["_type"] == "sys-system" and sysinfo["name"] == "IRB120-sim", sysinfo
    assert sysinfo["rwversion"].startswith("6.") and sysinfo["rwversionname"].startswith("6."), sysinfo
    mods = rws._do_get("rw/rapid/modules?task=T_ROB1")["_embedded"]["_state"]
    assert "CalibServer" in [m["name"] for m in mods if m["_type"] == "rap-module-info-li"], mods
    assert rws.get_tasks()["T_ROB1"].motiontask
    rws.set_rapid_variable("calib_dp", "[1.5,-2,0]")
    assert rws.get_rapid_variable("calib_dp") == "[1.5,-2,0]"
    # A move through the calibd RAPID module, driven only by RWS variable writes.
    target = [12.0, -4.0, 6.0, 0.0, 33.0, 1.0]
    rws.set_rapid_variable("calib_q", "[[" + ",".join(str(v) for v in target) + "],[9E9,9E9,9E9,9E9,9E9,9E9]]")
    rws.set_rapid_variable_num("calib_cmd", 1)
    rws.set_rapid_variable_num("calib_seq", 1)
    deadline = time.time() + 5
    while rws.get_rapid_variable_num("calib_ack") != 1:
        assert time.time() < deadline, "calib_ack never reached 1"
        time.sleep(0.02)
    jt = rws.get_jointtarget()
    assert np.allclose(jt.robax, target, atol=1e-3), jt
    try:
        rws.get_rapid_variable("no_such_var")
        raise AssertionError("unknown variable did not fail")
    except Exception as e:  # ABBException carries the RWS status code
        assert "not found" in str(e), e
    bad = RWS(base, "Default User", "wrong")
    try:
        bad.get_jointtarget()
        raise AssertionError("wrong password accepted")
    except Exception as e:
        assert "401" in str(e) or "Unauthorized" in str(e), e
    print(f"abb-robot-client OK: Digest auth, jointtarget, robtarget, RAPID set/get, move to {target}")


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]))
