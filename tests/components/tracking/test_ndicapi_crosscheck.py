"""Spec: a real NDI client library accepts the simulated Vicra. ndicapi (the combined-API
C library PLUS and scikit-surgery drive Polaris trackers with) probes it, sets it up
from a `.rom` tool definition fw wrote, and streams BX and TX from it, with NDI's error
numbering; the simulator runs in its own process on a real pseudo-terminal."""

import subprocess
import sys

import ndicapy as ndi_c
import pytest

from components.tracking.ndi_driver import load_tools
from components.tracking.ndi_rom import make_srom
from tests.conftest import REPO

SIMULATOR = """
import sys, time
from components.tracking.vicra_sim import ScenePose, VicraDevice
device = VicraDevice(sys.argv[1], seed=1)
device.plug()
device.scene["cto"] = ScenePose((10.0, 20.0, 900.0))
print("ready", flush=True)
sys.stdin.read()  # until the test closes our stdin
"""


@pytest.fixture
def device(tmp_path):
    link = tmp_path / "ttyVICRA"
    proc = subprocess.Popen(
        [sys.executable, "-c", SIMULATOR, str(link)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
        cwd=REPO,
    )
    assert proc.stdout.readline().strip() == "ready"
    yield str(link)
    proc.stdin.close()
    proc.wait(10)


def test_ndicapi_probes_sets_up_and_streams_the_simulated_vicra(device, tmp_path):
    assert ndi_c.ndiProbe(device) == ndi_c.NDI_OKAY
    handle_of = ndi_c.ndiOpen(device)
    try:
        assert ndi_c.ndiCommand(handle_of, "INIT:") == "OKAY"
        assert ndi_c.ndiCommand(handle_of, "COMM:50000") == "OKAY"
        assert "Freeze Tag: Polaris Vicra" in ndi_c.ndiCommand(handle_of, "VER:4")
        ndi_c.ndiCommand(handle_of, "PHRQ:*********1****")
        handle = ndi_c.ndiGetPHRQHandle(handle_of)
        cto = next(
            t for t in load_tools(REPO / "procedures" / "seeg" / "tools.yaml") if t.name == "cto"
        )
        rom = tmp_path / "cto.rom"
        rom.write_bytes(make_srom(cto.markers, "cto"))
        assert ndi_c.ndiPVWRFromFile(handle_of, handle, str(rom)) == 0
        assert ndi_c.ndiCommand(handle_of, f"PINIT:{handle:02X}") == "OKAY"
        assert ndi_c.ndiCommand(handle_of, f"PENA:{handle:02X}D") == "OKAY"
        ndi_c.ndiCommand(handle_of, "PHSR:00")
        assert ndi_c.ndiGetPHSRNumberOfHandles(handle_of) == 1
        assert ndi_c.ndiGetPHSRHandle(handle_of, 0) == handle
        with pytest.raises(OSError, match="0x2b: Requested handle has not been allocated"):
            ndi_c.ndiCommand(handle_of, "PENA:7FD")
        with pytest.raises(OSError, match="0x0c: Command is invalid while in the current mode"):
            ndi_c.ndiCommand(handle_of, "TX:0801")
        assert ndi_c.ndiCommand(handle_of, "TSTART:") == "OKAY"
        key = bytes([handle])
        ndi_c.ndiCommand(handle_of, "BX:0801")
        q0, qx, qy, qz, x, y, z, error = ndi_c.ndiGetBXTransform(handle_of, key)
        assert (q0, qx, qy, qz) == (1.0, 0.0, 0.0, 0.0)
        assert (x, y, z) == pytest.approx((10.0, 20.0, 900.0), abs=1.5)
        assert error == pytest.approx(0.25)
        assert ndi_c.ndiGetBXPortStatus(handle_of, key) == 0x31
        ndi_c.ndiCommand(handle_of, "TX:0801")
        assert ndi_c.ndiGetTXTransform(handle_of, key)[4:7] == pytest.approx((10, 20, 900), abs=1.5)
        assert ndi_c.ndiGetTXPortStatus(handle_of, key) == 0x31
        assert ndi_c.ndiCommand(handle_of, "TSTOP:") == "OKAY"
    finally:
        ndi_c.ndiClose(handle_of)
