"""Conformance: python-can 4.6.1 (interface='socketcand') with canopen 2.4.1 as the SDO
client, against calibd's socketcand hub mock with its CiA 402 drive (node 1).

Usage: python canopen_check.py HOST PORT
"""
import sys
import time

import canopen


def u16(b):
    return int.from_bytes(b, "little")


def main(host, port):
    net = canopen.Network()
    net.connect(interface="socketcand", host=host, port=port, channel="can0")
    try:
        node = canopen.RemoteNode(1, canopen.ObjectDictionary())
        net.add_node(node)
        sw = u16(node.sdo.upload(0x6041, 0))
        assert sw == 0x0250, hex(sw)  # switch on disabled, voltage enabled, remote
        # Identity (calibd lab check): 0x1018 expedited, 0x1008 by canopen's segmented upload.
        ident = [int.from_bytes(node.sdo.upload(0x1018, s), "little") for s in (1, 2, 3, 4)]
        assert ident == [0x00CA1BD0, 0x402, 0x00010003, 0x1234], [hex(v) for v in ident]
        name = node.sdo.upload(0x1008, 0).decode()
        assert name == "calibd CiA402 sim", name
        for cw, want in ((0x06, 0x21), (0x07, 0x23), (0x0F, 0x27)):
            node.sdo.download(0x6040, 0, cw.to_bytes(2, "little"))
            sw = u16(node.sdo.upload(0x6041, 0))
            assert sw & 0x6F == want, (hex(cw), hex(sw))
        node.sdo.download(0x6060, 0, (1).to_bytes(1, "little", signed=True))
        node.sdo.download(0x607A, 0, (100000).to_bytes(4, "little", signed=True))
        node.sdo.download(0x6040, 0, (0x1F).to_bytes(2, "little"))
        deadline = time.time() + 5
        while not u16(node.sdo.upload(0x6041, 0)) & (1 << 12):
            assert time.time() < deadline, "no set-point acknowledge"
        node.sdo.download(0x6040, 0, (0x0F).to_bytes(2, "little"))
        while not u16(node.sdo.upload(0x6041, 0)) & (1 << 10):
            assert time.time() < deadline, "target not reached"
            time.sleep(0.01)
        pos = int.from_bytes(node.sdo.upload(0x6064, 0), "little", signed=True)
        assert pos == 100000, pos
        try:
            node.sdo.upload(0x1234, 0)
            raise AssertionError("missing object did not abort")
        except canopen.SdoAbortedError as e:
            assert e.code == 0x06020000, hex(e.code)
        try:
            node.sdo.download(0x6041, 0, b"\x00\x00")
            raise AssertionError("read-only object accepted a write")
        except canopen.SdoAbortedError as e:
            assert e.code == 0x06010002, hex(e.code)
        print(f"python-can + canopen OK: identity {name!r} vendor {ident[0]:#x}, enabled the drive, profile-position move to {pos}, aborts 0x06020000/0x06010002")
    finally:
        net.disconnect()


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]))
