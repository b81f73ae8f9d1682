"""Conformance: the third-party qtm-rt 3.1.0 client (asyncio) against calibd's QTM mock.

Usage: python qtm_rt_check.py HOST PORT   (PORT = the mock's little-endian RT port)
"""
import asyncio
import sys
import xml.etree.ElementTree as ET

import qtm_rt


async def main(host, port):
    conn = await qtm_rt.connect(host, port=port, version="1.25", timeout=5)
    assert conn is not None, "qtm_rt.connect failed"
    state = await conn.get_state()
    assert state == qtm_rt.QRTEvent.EventConnected, state
    xml = await conn.get_parameters(["3d"])
    if isinstance(xml, bytes):
        xml = xml.decode()
    root = ET.fromstring(xml)
    labels = [l.find("Name").text for l in root.iter("Label")]
    assert labels == ["tool_a", "tool_b", "tool_c", "base"], labels
    # Identity (calibd lab check): capture frequency from General/Frequency.
    general = await conn.get_parameters(["general"])
    if isinstance(general, bytes):
        general = general.decode()
    freq = ET.fromstring(general).find("General/Frequency").text
    assert freq == "100", freq
    frames = []

    def on_packet(packet):
        _, markers = packet.get_3d_markers()
        frames.append((packet.framenumber, [(m.x, m.y, m.z) for m in markers]))

    await conn.stream_frames(components=["3d"], on_packet=on_packet)
    await asyncio.sleep(1.0)
    await conn.stream_frames_stop()
    conn.disconnect()
    assert len(frames) >= 50, len(frames)
    numbers = [f for f, _ in frames]
    assert all(b == a + 1 for a, b in zip(numbers, numbers[1:])), "frame numbers not consecutive"
    assert all(len(m) == 4 for _, m in frames)
    # Marker tool_a runs on a 50 mm circle around (500, 200) mm.
    for _, m in frames:
        x, y, z = m[0]
        r = ((x - 500.0) ** 2 + (y - 200.0) ** 2) ** 0.5
        assert abs(r - 50.0) < 1e-3 and z == 1000.0, (x, y, z)
    occluded = sum(1 for _, m in frames if m[3][0] != m[3][0])
    print(f"qtm-rt OK: state {state.name}, {freq} Hz, labels {labels}, {len(frames)} frames, "
          f"{occluded} with 'base' occluded (NaN)")


if __name__ == "__main__":
    asyncio.run(main(sys.argv[1], int(sys.argv[2])))
