"""`agrislam live` as a process: a survey replayed to it with `agrislam replay`, then
SIGINT: it writes the outputs of `agrislam run` and exits 0, and `agrislam run` of its
recording gives the same map."""

import os
import signal
import subprocess
import sys
import time

import numpy as np
from typer.testing import CliRunner

from agrislam.cli import app
from paths import SRC

runner = CliRunner()


def test_live_stops_on_sigint_with_the_outputs_of_run_and_its_recording_maps_alike(
    tmp_path, endpoint
):
    out = tmp_path / "live"
    env = {**os.environ, "PYTHONPATH": f"{SRC}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    live = subprocess.Popen(
        [sys.executable, "-c", "from agrislam.cli import app; app()", "live", "--out",
         str(out), "--listen", endpoint],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    try:
        assert "mapping live" in live.stdout.readline()  # it listens now
        replayed = runner.invoke(
            app, ["replay", "sim:?plants=30&seed=5", "--rate", "0", "--connect", endpoint]
        )
        assert replayed.exit_code == 0, replayed.output
        assert "published" in replayed.output
        time.sleep(0.5)
        live.send_signal(signal.SIGINT)
        output, _ = live.communicate(timeout=120)
    finally:
        live.kill()
        live.communicate()
    assert live.returncode == 0, output
    for name in ("live.mcap", "objects.csv", "map.mcap", "metrics.json", "report.png"):
        assert (out / name).exists(), name
    offline = tmp_path / "offline"
    ran = runner.invoke(app, ["run", str(out / "live.mcap"), "--out", str(offline)])
    assert ran.exit_code == 0, ran.output
    a, b = (np.loadtxt(d / "objects.csv", delimiter=",", skiprows=1, usecols=(0, 1, 2))
            for d in (out, offline))  # fmt: skip
    assert len(a) > 10 and np.array_equal(a[:, 0], b[:, 0])
    assert np.abs(a[:, 1:] - b[:, 1:]).max() <= 1e-6
