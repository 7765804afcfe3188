"""metrics.json's document helpers (senerf.train.record)."""

from __future__ import annotations


def test_finished_metrics_reads_a_run_through_the_iteration_asked_for(tmp_path):
    import json

    from senerf.train import finished_metrics

    assert finished_metrics(tmp_path) is None                          # no metrics.json
    (tmp_path / "metrics.json").write_text("{not json")
    assert finished_metrics(tmp_path) is None
    (tmp_path / "metrics.json").write_text(json.dumps({"iterations": []}))
    assert finished_metrics(tmp_path, 0) is None                       # written before iteration 0 finished
    doc = {"iterations": [{"iteration": 0}, {"iteration": 1}]}
    (tmp_path / "metrics.json").write_text(json.dumps(doc))
    assert finished_metrics(tmp_path, 0) == doc and finished_metrics(tmp_path, 1) == doc
    assert finished_metrics(tmp_path, 2) is None                       # iteration 2 not finished
    (tmp_path / "metrics.json").write_text(json.dumps([1, 2]))
    assert finished_metrics(tmp_path) is None                          # not a metrics document


def test_each_row_records_the_host_that_finished_it(monkeypatch):
    """A fit's figures depend on torch's thread count on the CPU (the float sums' order) and are not repeatable
    on CUDA: every row says where it was made (device, threads, torch and NumPy versions)."""
    import numpy as np
    import torch

    from senerf.fields.ckernel import cpu_planes_path
    from senerf.memory import cpu_model
    from senerf.train import host_record, iteration_row

    ev = {"psnr": 20.0, "ssim": 0.5, "lpips": "unavailable", "avg": "unavailable", "per_view": {"psnr": [20.0]}}
    threads = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        assert host_record("cpu") == {"device": "cpu", "threads": 1, "cpu": cpu_model(), "torch": torch.__version__,
                                      "numpy": np.__version__, "kernel": cpu_planes_path()}
        torch.set_num_threads(2)
        row = iteration_row(1, ev, 0.25, 3.0, torch.device("cpu"))
    finally:
        torch.set_num_threads(threads)
    assert row["host"]["threads"] == 2 and row["host"]["device"] == "cpu"
    assert {k: row[k] for k in ("iteration", "psnr", "reliable_fraction", "seconds")} == {
        "iteration": 1, "psnr": 20.0, "reliable_fraction": 0.25, "seconds": 3.0}
    # a GPU is named, not just "cuda" (no GPU needed to check: torch is asked for the name)
    monkeypatch.setattr(torch.cuda, "get_device_name", lambda device=None: f"Fake GPU {torch.device(device)}")
    assert host_record("cuda:1")["device"] == "Fake GPU cuda:1"
    assert "kernel" not in host_record("cuda:1")   # the compiled kernel is the CPU's
    assert iteration_row(1, ev, None, 1.0, "cuda:1")["host"]["device"] == "Fake GPU cuda:1"


def test_host_change_names_what_differs_in_words():
    from senerf.train import host_change

    here = {"device": "cpu", "threads": 2, "torch": "2.13.0", "numpy": "2.3.0"}
    assert host_change(None, here) == "" and host_change(here, here) == ""   # None: written before hosts were recorded
    assert host_change(dict(here, device="NVIDIA H100"), here) == "on NVIDIA H100, this call on cpu"
    assert host_change(dict(here, threads=2), dict(here, threads=1)) == "with 2 threads, this call with 1 thread"
    assert host_change(dict(here, threads=1, torch="2.11.0"), here) == (
        "with 1 thread, with torch 2.11.0, this call with 2 threads, with torch 2.13.0")
    assert host_change(dict(here, cpu="AMD EPYC 9B14"), dict(here, cpu="Intel(R) Xeon(R) Processor")) == (
        "with processor AMD EPYC 9B14, this call with processor Intel(R) Xeon(R) Processor")
    assert host_change(dict(here, kernel="compiled"), dict(here, kernel="pytorch")) == (
        "with the compiled K-Planes code, this call with the pytorch K-Planes code")
    # a key only one side records (a later version's, or an earlier one's) is not a difference
    assert host_change({"device": "cpu", "threads": 2}, dict(here, threads=2)) == ""
    assert host_change(dict(here, threads=2), {"device": "cpu", "threads": 2}) == ""
    assert host_change("not a record", here) == "" and host_change(5, here) == ""


def test_a_resume_names_another_host_on_the_cpu_only(monkeypatch):
    """On the CPU a run repeats to the bit for the same host, so a resume names what differs; on a GPU runs do not
    repeat to the bit anyway and the CPU thread count hardly matters, so nothing is said there."""
    import torch

    import senerf.train.record as record_mod
    from senerf.train import host_record, resume_host_line

    here = host_record("cpu")
    threads = f"{here['threads']} thread" + ("" if here["threads"] == 1 else "s")
    assert resume_host_line(dict(here, threads=here["threads"] + 1), "cpu", "step 5 ran") == (
        f"step 5 ran with {here['threads'] + 1} threads, this call with {threads}: the rest is reproducible, but not "
        f"bit for bit an uninterrupted run")
    assert resume_host_line(here, torch.device("cpu"), "x") == "" and resume_host_line(None, "cpu", "x") == ""
    monkeypatch.setattr(record_mod, "host_record", lambda device: dict(here, device="Fake GPU"))
    assert resume_host_line(dict(here, device="Fake GPU", threads=here["threads"] + 1), "cuda:0", "x") == ""


def test_the_host_record_says_when_k_planes_runs_without_its_compiled_kernel(monkeypatch):
    """Catches: a machine without a C compiler silently running the pure-PyTorch planes (1.6x slower, other bits)
    with rows that look like the kernel's (session 24)."""
    import senerf.fields.ckernel as ck
    from senerf.train import host_record

    monkeypatch.setattr(ck, "load_kernel", lambda dtype, n_features=16: None)
    monkeypatch.setitem(ck._STATUS, "status", "unavailable: OSError: no C compiler found")
    assert host_record("cpu")["kernel"] == "pytorch"
    line = ck.cpu_planes_warning(16)
    assert line.startswith("the compiled K-Planes kernel cannot be used (OSError: no C compiler found); the "
                           "pure-PyTorch path runs instead")
    assert "more than 256 features per plane" in ck.cpu_planes_warning(300)
    monkeypatch.setattr(ck, "load_kernel", lambda dtype, n_features=16: object())
    assert host_record("cpu")["kernel"] == "compiled" and ck.cpu_planes_warning(16) is None
    monkeypatch.undo()   # the real loader refuses a count past MAX_FEATURES itself
    assert ck.cpu_planes_path(300) == "pytorch"   # past MAX_FEATURES the fields take the PyTorch path
