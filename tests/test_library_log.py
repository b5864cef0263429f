"""The libraries' warnings go to fdigen's log file, not into the user's output: a tune
executor started while another process holds Dask's dashboard port 8787 (loopback) prints
nothing, and a library warning lands in ``$FDIGEN_CACHE/fdigen.log``."""

import socket
import subprocess
import sys
import textwrap

SCRIPT = textwrap.dedent("""
    import warnings

    if __name__ == "__main__":
        from fdigen.library_log import route_library_output
        from fdigen.tune.campaign import CampaignExecutor

        path = route_library_output()
        with CampaignExecutor(workers=1, progress=False) as ex:
            assert ex.client is not None
            ex.client.run(warnings.warn, "worker warning from a library")
        warnings.warn("a library's warning")
        print(path)
""")


def test_tune_executor_output_is_clean_with_port_8787_taken(tmp_path):
    holder = socket.socket()
    try:
        holder.bind(("127.0.0.1", 8787))
        holder.listen()
    except OSError:          # already held (another cluster on this machine): as wanted
        holder.close()
        holder = None
    try:
        script = tmp_path / "run.py"
        script.write_text(SCRIPT)
        env = {"FDIGEN_CACHE": str(tmp_path / "cache"), "PATH": "/usr/bin:/bin",
               "HOME": str(tmp_path)}
        proc = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                              timeout=300, env=env, cwd=tmp_path)
    finally:
        if holder is not None:
            holder.close()
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr == "", proc.stderr            # no "Port 8787 is already in use"
    log = tmp_path / "cache" / "fdigen.log"
    assert proc.stdout.strip() == str(log)
    text = log.read_text(encoding="utf-8")
    assert "a library's warning" in text and "worker warning from a library" in text
    assert "8787" not in text                        # the port is not even tried
