"""Helpers shared by the simulator tests (not a test module)."""

import os

import pytest


def require_sim():
    """Skip (or fail when CALIBGRAPH_SIM_REQUIRED=1) without MuJoCo, franky-sim or headless GL."""
    try:
        from calibgraph.sim.scene import fr3_xml_path, import_mujoco

        mj = import_mujoco()
        fr3_xml_path()
        m = mj.MjModel.from_xml_string("<mujoco><worldbody><geom size='1'/></worldbody></mujoco>")
        r = mj.Renderer(m, 8, 8)
        r.close()
    except Exception as e:  # any missing piece means: no simulator here
        msg = f"simulator unavailable: {type(e).__name__}: {e}"
        if os.environ.get("CALIBGRAPH_SIM_REQUIRED") == "1":
            pytest.fail(msg)
        pytest.skip(msg)
