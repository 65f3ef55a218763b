"""docs/examples/diagnose.ipynb runs: it is executed here with nbclient in a
python3 kernel of this interpreter, in a fresh working directory holding the
model it reads, so the example cannot rot. Every cell must run without an
error, the diagnosis must show its verdict in words and a picture, the
figures must show as images, and the report folder must be written. The
committed notebook keeps no outputs.

Skipped, saying why, when nbclient, nbformat or ipykernel is missing or the
kernel does not start."""

import json
import shutil
import sys

import pytest

from conftest import ROOT

NOTEBOOK = ROOT / "docs" / "examples" / "diagnose.ipynb"


def test_the_committed_notebook_keeps_no_outputs():
    nb = json.loads(NOTEBOOK.read_text(encoding="utf-8"))
    code = [c for c in nb["cells"] if c["cell_type"] == "code"]
    assert code
    assert all(c["outputs"] == [] and c["execution_count"] is None for c in code)


def _kernel(tmp_path):
    """A kernel manager of a ``python3`` kernel spec that runs this
    interpreter (not whatever ``python3`` a user's Jupyter knows)."""
    from jupyter_client import KernelManager
    from jupyter_client.kernelspec import KernelSpecManager

    spec = tmp_path / "kernels" / "python3"
    spec.mkdir(parents=True)
    (spec / "kernel.json").write_text(json.dumps({
        "argv": [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"],
        "display_name": "Python 3 (bgc tests)", "language": "python"}), encoding="utf-8")
    specs = KernelSpecManager(kernel_dirs=[str(spec.parent)], ensure_native_kernel=False)
    return KernelManager(kernel_name="python3", kernel_spec_manager=specs)


@pytest.mark.process  # a Jupyter kernel: a process of its own
def test_the_example_notebook_runs_and_shows_the_verdict_a_picture_and_writes_the_folder(tmp_path, monkeypatch):
    nbformat = pytest.importorskip("nbformat", reason="nbformat is needed to read the notebook (pip install .[test])")
    nbclient = pytest.importorskip("nbclient", reason="nbclient is needed to run the notebook (pip install .[test])")
    pytest.importorskip("ipykernel", reason="ipykernel is needed for the notebook's kernel (pip install .[test])")

    work = tmp_path / "work"  # the notebook finds models/ from its working directory up
    (work / "models").mkdir(parents=True)
    shutil.copy(ROOT / "models" / "two_tank.yaml", work / "models")
    monkeypatch.setenv("PYTHONPATH", str(ROOT))  # the kernel imports this checkout's bgc
    nb = nbformat.read(NOTEBOOK, as_version=4)
    client = nbclient.NotebookClient(nb, timeout=300, km=_kernel(tmp_path), allow_errors=False,
                                     resources={"metadata": {"path": str(work)}})
    client.reset_execution_trackers()
    started = False
    try:
        with client.setup_kernel():
            started = True
            for index, cell in enumerate(nb.cells):
                client.execute_cell(cell, index)
    except Exception as exc:  # noqa: BLE001 - a kernel that does not start is the machine's, not the notebook's
        if started:
            raise
        pytest.skip(f"the python3 kernel does not start: {type(exc).__name__}: {exc}")

    code = [c for c in nb.cells if c.cell_type == "code"]
    errors = [o for c in code for o in c.outputs if o.output_type == "error"]
    assert not errors, errors
    bundles = [o.get("data", {}) for c in code for o in c.outputs if o.output_type in ("execute_result", "display_data")]
    pages = [b["text/html"] for b in bundles if "text/html" in b]
    # the session's view, then the diagnosis's: the verdict in words with its picture embedded
    assert any("Model two_tank" in page and "Fault candidates" in page for page in pages)
    (report,) = [page for page in pages if "Diagnosis of two_tank" in page]
    assert "Fault isolated: R12_abrupt." in report and 'src="data:image/png;base64,' in report
    printed = "".join(o.get("text", "") for c in code for o in c.outputs if o.output_type == "stream")
    assert "verdict: isolated: R12_abrupt" in printed
    assert sum("image/png" in b for b in bundles) >= 2  # the two figures shown
    folder = work / "two_tank-diagnosis"
    assert {"report.html", "report.md", "report.json", "estimate.png", "manifest.json", "run.csv"} <= {
        p.name for p in folder.iterdir()}
    assert json.loads((folder / "report.json").read_text(encoding="utf-8"))["diagnosis"] == ["R12_abrupt"]
