"""benchmarks/bench_selftrain.py: the reliability-mask result as a markdown table and a bar plot; the similarity
benchmark on tiny inputs."""

from __future__ import annotations

import argparse

import imageio.v3 as iio
import pytest
import torch

from senerf.fields.ckernel import load_kernel


def test_masks_result_as_a_table_and_a_plot(tmp_path, load_script):
    mod = load_script("bench_selftrain")
    row = dict(features="vgg19-norm", threshold="adaptive", tau=0.9475, precision=0.9265, recall=0.165, fpr=0.0672,
               predicted_reliable_rate=0.149, gt_reliable_rate=0.837)
    doc = dict(rows=[row, dict(row, threshold="unified", tau=None)], eval_angles_deg=[3.9, 11.9], steps=600,
               argv=["benchmarks/bench_selftrain.py", "masks"], commit="abc", batch_rays=1024, teacher_psnr=16.57,
               max_error=0.1, timestamp="2026-11-21T09:00")
    text = mod.mask_quality_markdown(doc, "bench_masks.json")
    assert "| vgg19-norm | adaptive | 0.948 | 92.65 % | 16.50 % | 6.72 % | 14.90 % | 83.70 % |" in text
    assert "| vgg19-norm | unified | soft |" in text and "3.9-11.9 degrees" in text and "commit abc" in text
    png = mod.plot_mask_quality(doc["rows"], tmp_path / "mask.png", "masks")
    assert iio.imread(png).ndim == 3


def test_the_similarity_benchmark_times_the_kernel_against_numpy_on_the_same_lookups(load_script):
    if load_kernel(torch.float32) is None:
        pytest.skip("no compiled kernel to time")
    mod = load_script("bench_selftrain")
    args = argparse.Namespace(height=7, width=9, channels=20, pixels=50, repeats=2, seed=0)
    res = mod.bench_similarity(args)
    assert res["pixels"] == 50 and res["size"] == [7, 9] and res["channels"] == 20
    assert res["numpy_seconds"] > 0 and res["kernel_seconds"] > 0 and res["max_abs_difference"] < 1e-6
