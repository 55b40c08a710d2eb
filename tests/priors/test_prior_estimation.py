"""Size priors from ground truth: the robust Gaussian, its consistency factor, samples per class or per track."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from tests.eval_scenes import write_cityscapes
from toosicubix.annotations import priors_file
from toosicubix.annotations.priors_file import load_priors
from toosicubix.errors import FormatError
from toosicubix.priors.estimation import (
    CITYSCAPES_KITTI_TYPES,
    DimensionSamples,
    PriorEstimationError,
    collect_dimensions,
    estimate_priors,
    format_sequences,
    make_positive_definite,
    outer_product_median_factor,
    outer_products,
    priors_document,
    repeated_share,
    robust_gaussian,
    write_priors_file,
)
from toosicubix.priors.geometric_median import geometric_median
from toosicubix.size_priors import bundled_priors_path

# A realistic car: KITTI-like mean and spread (length, width, height), with correlated axes.
CAR_MEAN = np.array([3.9, 1.62, 1.51])
CAR_STD = np.array([0.42, 0.11, 0.12])
CAR_CORR = np.array([[1.0, 0.5, 0.1], [0.5, 1.0, 0.3], [0.1, 0.3, 1.0]])
CAR_COV = CAR_CORR * np.outer(CAR_STD, CAR_STD)
N = 4000


# --- helpers shared with test_cli_priors ------------------------------------------------------------------


def tracking_line(frame: int, track: int, type_: str, lwh: tuple[float, float, float]) -> str:
    """One KITTI tracking label line (17 fields) with dimensions (l, w, h)."""
    length, width, height = lwh
    return f"{frame} {track} {type_} 0 0 -1.5 100 150 200 250 {height:.2f} {width:.2f} {length:.2f} 2.0 1.6 20.0 -1.57"


def write_tracking(root: Path, sequences: dict[str, list[str]]) -> Path:
    """``root/label_02/<seq>.txt`` from label lines; returns root."""
    (root / "label_02").mkdir(parents=True)
    for name, lines in sequences.items():
        (root / "label_02" / f"{name}.txt").write_text("".join(f"{ln}\n" for ln in lines))
    return root


def small_tracking(root: Path) -> Path:
    """Sequence 0000: Car track 1 in 100 frames, Car tracks 2-4 in one frame each, a Van track in 3 frames, a
    DontCare row; sequence 0001: another Car track 1 (a different vehicle) and a Truck track."""
    seq0 = [tracking_line(f, 1, "Car", (4.0, 1.6, 1.5)) for f in range(100)]
    seq0 += [tracking_line(5, t, "Car", (3.6 + 0.2 * t, 1.6, 1.45)) for t in (2, 3, 4)]
    seq0 += [tracking_line(f, 7, "Van", (5.0, 1.9, 2.1)) for f in (0, 1, 2)]
    seq0 += ["3 -1 DontCare -1 -1 -10 300 150 320 170 -1000 -1000 -1000 -1000 -1000 -1000 -10"]
    seq1 = [tracking_line(0, 1, "Car", (4.5, 1.8, 1.6)), tracking_line(1, 2, "Truck", (9.0, 2.5, 3.3))]
    return write_tracking(root, {"0000": seq0, "0001": seq1})


# --- the consistency factor c ------------------------------------------------------------------------------


def test_consistency_factor_in_one_dimension_is_the_median_of_chi_square_1():
    # In R^1 the geometric median is the ordinary median: an independent check of the integral and the root.
    # brentq's tolerance is 1e-13 and quad's error ~1e-10 on this smooth integrand: 1e-9 holds.
    assert outer_product_median_factor(1) == pytest.approx(stats.chi2.median(1), abs=1e-9)


def test_consistency_factor_in_three_dimensions_matches_monte_carlo():
    c = outer_product_median_factor(3)
    assert c == pytest.approx(0.586264, abs=1e-6)  # the figure recorded in the priors' sources
    Z = np.random.default_rng(0).standard_normal((60_000, 3))
    M = geometric_median(outer_products(Z)).median.reshape(3, 3)
    # Calibrated over 60 seeded replications at n = 20,000: the mean diagonal entry has sd 0.0044 and no
    # visible bias (mean 0.5861); at n = 60,000 the sd is 0.0026, so 4 sd = 0.0104. Off-diagonal entries of
    # the 20,000-sample estimate stayed below 0.011; 0.02 bounds them here.
    assert np.trace(M) / 3 == pytest.approx(c, abs=0.0104)
    assert np.abs(M - np.diag(np.diag(M))).max() < 0.02


def test_consistency_factor_rejects_dimension_zero():
    with pytest.raises(ValueError, match="dimension >= 1"):
        outer_product_median_factor(0)


# --- the robust Gaussian -----------------------------------------------------------------------------------


def test_whitened_estimate_recovers_a_correlated_gaussian(rng):
    X = rng.multivariate_normal(CAR_MEAN, CAR_COV, size=N)
    g = robust_gaussian(X, method="whitened")
    assert g.converged and g.n == N and g.floored_eigenvalues == 0
    # The spatial median's spread per axis was at most 1.19 times the sample mean's standard error
    # sigma / sqrt(n) over 150 seeded replications: 4 such standard errors.
    np.testing.assert_array_less(np.abs(g.mean - CAR_MEAN), 4 * 1.2 * CAR_STD / np.sqrt(N))
    # Over the same replications every covariance entry had sd <= 0.028 sqrt(S_ii S_jj) and bias < 0.6 %:
    # 4 sd = 0.12 sqrt(S_ii S_jj).
    scale = np.sqrt(np.outer(np.diag(CAR_COV), np.diag(CAR_COV)))
    np.testing.assert_array_less(np.abs(g.cov - CAR_COV), 0.12 * scale)
    np.testing.assert_allclose(g.cov, g.cov.T, rtol=0, atol=1e-15)


def test_paper_estimate_is_consistent_for_isotropic_spread(rng):
    sigma2 = 0.1**2
    X = CAR_MEAN + np.sqrt(sigma2) * rng.standard_normal((N, 3))
    g = robust_gaussian(X)
    assert g.method == "paper" and g.converged
    # 60 seeded replications: sd of cov / sigma^2 <= 0.024 on the diagonal, 0.015 off it: 4 sd.
    np.testing.assert_allclose(np.diag(g.cov) / sigma2, 1.0, atol=0.1)
    assert np.abs(g.cov / sigma2 - np.diag(np.diag(g.cov / sigma2))).max() < 0.06
    # The raw figure is recovered by multiplying by c (no eigenvalue was floored).
    np.testing.assert_allclose(g.cov * g.consistency_factor, g.cov_median, rtol=1e-12)


def test_sample_method_is_the_samples_own_mean_and_covariance(rng):
    X = rng.multivariate_normal(CAR_MEAN, CAR_COV, size=200)
    g = robust_gaussian(X, method="sample")
    assert g.method == "sample" and g.mean_fit is None and g.consistency_factor == 1.0 and g.floored_eigenvalues == 0
    np.testing.assert_allclose(g.mean, X.mean(axis=0), rtol=1e-14)
    np.testing.assert_allclose(g.cov, np.cov(X, rowvar=False, ddof=1), rtol=1e-12)
    with pytest.raises(ValueError, match="finite"):
        robust_gaussian(np.vstack([X, [np.nan, 1.0, 1.0]]), method="sample")


def test_medians_collapse_on_sizes_that_repeat_and_the_estimate_warns(rng):
    """A type's cars built from a few CAD models, one of them 40 % of the cars (as ApolloCar3D's SUVs): the
    paper's spread collapses toward the commonest model; the samples' own covariance does not."""
    models = CAR_MEAN + rng.multivariate_normal(np.zeros(3), CAR_COV, size=12)
    which = np.r_[np.zeros(80, dtype=int), rng.integers(1, 12, size=120)]
    X = models[which]
    assert repeated_share(X) == pytest.approx(0.4)
    truth = np.diag(np.cov(X, rowvar=False))
    paper, sample = robust_gaussian(X, method="paper"), robust_gaussian(X, method="sample")
    np.testing.assert_allclose(np.diag(sample.cov), truth, rtol=1e-12)
    # Seeded draw: the paper's total variance comes out at a quarter of the samples' (0.033 against 0.128 m^2;
    # the length's at 0.23 of it); half is the bound.
    assert np.trace(paper.cov) < 0.5 * truth.sum() and paper.cov[0, 0] < 0.5 * truth[0]
    samples = DimensionSamples(dimensions={"SUV": X}, kind="apollocar3d", root=Path("x.json"), unit="car")
    warned = estimate_priors(samples, method="paper").warnings
    assert any(w.startswith("SUV: 40 % of its samples are one repeated size") for w in warned)
    assert not any("repeated" in w for w in estimate_priors(samples, method="sample").warnings)
    assert repeated_share(rng.normal(size=(50, 3))) == pytest.approx(1 / 50)


def test_paper_estimate_is_biased_for_anisotropic_spread(rng):
    """The Frobenius median is not affine-equivariant: with a car's spread the paper's figure over c
    underestimates the length variance and overestimates the others (documented, not a bug)."""
    X = rng.multivariate_normal(CAR_MEAN, CAR_COV, size=N)
    ratio = np.diag(robust_gaussian(X, method="paper").cov) / np.diag(CAR_COV)
    # 150 replications gave ratios 0.77, 1.20, 1.26 (sd <= 0.03 each): bounds 3 sd inside those means.
    assert ratio[0] < 0.87 and ratio[1] > 1.1 and ratio[2] > 1.1


@pytest.mark.parametrize("method", ["paper", "whitened"])
def test_five_percent_gross_outliers_barely_move_the_robust_estimate(rng, method):
    X = rng.multivariate_normal(CAR_MEAN, CAR_COV, size=N)
    Y = X.copy()
    # 5 % buses labelled as cars.
    Y[: N // 20] = rng.multivariate_normal([12.0, 2.55, 3.2], np.diag([1.0, 0.01, 0.04]), size=N // 20)
    clean, dirty = robust_gaussian(X, method=method), robust_gaussian(Y, method=method)
    # Robust: the mean moves by under a quarter of a standard deviation per axis (0.07 sd seen), each
    # variance by under 30 % (17 % seen).
    np.testing.assert_array_less(np.abs(dirty.mean - clean.mean), 0.25 * CAR_STD)
    np.testing.assert_array_less(np.diag(dirty.cov) / np.diag(clean.cov), 1.3)
    # Classical: the mean length moves by about one standard deviation, the variances grow 4 to 19 times.
    assert abs(Y.mean(axis=0)[0] - X.mean(axis=0)[0]) > 0.8 * CAR_STD[0]
    assert np.all(np.diag(np.cov(Y.T)) / np.diag(np.cov(X.T)) > 4.0)


def test_two_samples_give_a_floored_positive_definite_covariance():
    g = robust_gaussian(np.array([[4.0, 1.6, 1.5], [4.4, 1.7, 1.5]]))
    # Both deviations from the midpoint have the same outer product: rank 1, two eigenvalues floored.
    assert g.floored_eigenvalues == 2
    assert np.linalg.eigvalsh(g.cov).min() > 0.0
    np.testing.assert_allclose(g.mean, [4.2, 1.65, 1.5], rtol=0, atol=1e-12)


def test_make_positive_definite_floors_and_symmetrizes():
    S, floored = make_positive_definite(np.array([[1.0, 0.0], [1e-3, 0.0]]))
    assert floored == 1
    np.testing.assert_array_equal(S, S.T)
    assert np.linalg.eigvalsh(S).min() == pytest.approx(1e-6, rel=1e-6)  # max(1e-6 m^2, 1e-6 x largest)
    same, none = make_positive_definite(CAR_COV)
    assert none == 0 and np.array_equal(same, CAR_COV)


def test_robust_gaussian_rejects_one_sample_and_unknown_methods():
    with pytest.raises(ValueError, match="at least 2 samples"):
        robust_gaussian(np.array([[4.0, 1.6, 1.5]]))
    with pytest.raises(ValueError, match="unknown method"):
        robust_gaussian(np.eye(3), method="mean")  # type: ignore[arg-type]


# --- samples from ground truth -----------------------------------------------------------------------------


def test_tracking_counts_every_track_once(tmp_path):
    samples = collect_dimensions("kitti-tracking", small_tracking(tmp_path))
    assert samples.unit == "track"
    # Car: track 1 of 0000 (100 rows) once, tracks 2-4 of 0000, track 1 of 0001: 5.
    assert {name: len(d) for name, d in samples.dimensions.items()} == {"Car": 5, "Van": 1, "Truck": 1}
    np.testing.assert_array_equal(samples.dimensions["Car"][0], [4.0, 1.6, 1.5])
    assert samples.notes == ()


def test_tracking_sequences_and_classes_select(tmp_path):
    root = small_tracking(tmp_path)
    samples = collect_dimensions("kitti-tracking", root, classes=["car", "Tram"], sequences=["0001"])
    assert {name: len(d) for name, d in samples.dimensions.items()} == {"Car": 1}
    assert samples.missing == ("Tram",)
    assert "sequences 0001, one sample per track" in samples.describe()
    with pytest.raises(PriorEstimationError, match=r"0007\.txt"):
        collect_dimensions("kitti-tracking", root, sequences=["0007"])


def test_tracking_rows_that_disagree_use_their_median(tmp_path):
    lines = [tracking_line(f, 1, "Car", (4.0 + (0.5 if f == 2 else 0.0), 1.6, 1.5)) for f in range(5)]
    samples = collect_dimensions("kitti-tracking", write_tracking(tmp_path, {"0003": lines}))
    np.testing.assert_allclose(samples.dimensions["Car"][0], [4.0, 1.6, 1.5], atol=1e-9)  # 4 of 5 rows agree
    assert samples.notes == ("1 tracks have rows with differing dimensions; the geometric median of each was used",)


def test_kitti_object_counts_every_object_and_skips_dontcare(tmp_path):
    (tmp_path / "label_2").mkdir()
    line = "{} 0.00 0 -1.5 100 150 200 250 1.50 1.60 {:.2f} 2.0 1.6 20.0 -1.57"
    (tmp_path / "label_2" / "000001.txt").write_text(
        "\n".join([line.format("Car", 4.0), line.format("Car", 4.2), line.format("Van", 5.0),
                   "DontCare -1 -1 -10 300 150 320 170 -1 -1 -1 -1000 -1000 -1000 -10"]) + "\n")
    (tmp_path / "label_2" / "000002.txt").write_text(line.format("Car", 3.8) + "\n")
    samples = collect_dimensions("kitti", tmp_path)
    assert samples.unit == "object"
    assert {name: len(d) for name, d in samples.dimensions.items()} == {"Car": 3, "Van": 1}
    assert samples.missing == ("Truck",)


def test_malformed_tracking_label_names_file_and_line(tmp_path):
    root = write_tracking(tmp_path, {"0000": [tracking_line(0, 1, "Car", (4.0, 1.6, 1.5)), "0 2 Car 0 0"]})
    with pytest.raises(FormatError, match=r"0000\.txt:2: expected 17 or 18 fields"):
        collect_dimensions("kitti-tracking", root)


def test_sequences_only_for_tracking(tmp_path):
    with pytest.raises(PriorEstimationError, match="KITTI tracking"):
        collect_dimensions("kitti", tmp_path, sequences=["0000"])


def test_cityscapes_groups_by_prototype_type(tmp_path):
    samples = collect_dimensions("cityscapes", write_cityscapes(tmp_path))
    # Default classes: every prototype type of a vehicle box, sorted.
    assert {name: len(d) for name, d in samples.dimensions.items()} == {
        "Bicycle": 1, "Mid Size Car": 4, "Mini Truck": 1}
    estimates = estimate_priors(samples, min_samples=3)
    assert list(estimates.classes) == ["Mid Size Car"]
    assert estimates.classes["Mid Size Car"].kitti_type == "Car"
    assert estimates.skipped == ("Bicycle", "Mini Truck")
    assert "Mini Truck: only 1 sample; at least 2 are needed for a covariance, skipped" in estimates.warnings


def test_cityscapes_kitti_types():
    assert CITYSCAPES_KITTI_TYPES["Station Wagon"] == "Car"
    assert CITYSCAPES_KITTI_TYPES["Box Wagon"] == "Van"
    assert CITYSCAPES_KITTI_TYPES["Small Size Truck"] == "Truck"
    assert "Caravan" not in CITYSCAPES_KITTI_TYPES  # falls back to Misc


def test_format_sequences():
    assert format_sequences(["0000", "0001", "0002", "0005", "0007", "0008"]) == "0000-0002,0005,0007-0008"
    assert format_sequences(["0003"]) == "0003"


# --- priors per class and the file -------------------------------------------------------------------------


def test_estimates_warn_about_small_classes_and_record_provenance(tmp_path):
    samples = collect_dimensions("kitti-tracking", small_tracking(tmp_path))
    estimates = estimate_priors(samples, min_samples=4, command="toosicubix priors --kitti-tracking X")
    assert list(estimates.classes) == ["Car"]
    assert estimates.skipped == ("Van", "Truck")
    source = estimates.classes["Car"].source
    assert source.startswith("toosicubix priors --kitti-tracking X: KITTI tracking labels in ")
    assert "n=5;" in source and "divided by c=0.586264 (Gaussian consistency" in source
    assert not estimates.classes["Car"].few_samples
    few = estimate_priors(samples, min_samples=20)
    assert few.classes["Car"].few_samples
    assert "Car: only 5 samples (fewer than 20); written, but its spread is poorly determined" in few.warnings
    assert "only 5 samples (fewer than 20)" in few.classes["Car"].source


def test_document_keeps_base_entries_and_round_trips(tmp_path):
    samples = collect_dimensions("kitti-tracking", small_tracking(tmp_path / "gt"))
    estimates = estimate_priors(samples, min_samples=2)
    base = priors_file.load_priors_file(bundled_priors_path())
    doc = priors_document(estimates, base)
    assert list(doc.prototypes) == list(base.prototypes)  # Car replaced in place, nothing added
    assert doc.prototypes["Sedan"] == base.prototypes["Sedan"]
    assert doc.prototypes["Car"].n == 5 and not doc.prototypes["Car"].approximate
    path = tmp_path / "priors.json"
    write_priors_file(doc, path)
    assert priors_file.load_priors_file(path) == doc
    priors = load_priors(path)
    np.testing.assert_allclose(priors["Car"].mean, np.round(estimates.classes["Car"].gaussian.mean, 4))
    assert json.loads(path.read_text())["description"] == base.description


def test_document_without_base_has_only_the_estimates(tmp_path):
    estimates = estimate_priors(collect_dimensions("kitti-tracking", small_tracking(tmp_path)), min_samples=2)
    assert list(priors_document(estimates).prototypes) == ["Car"]


# --- the real KITTI tracking labels ------------------------------------------------------------------------


def test_tuning_split_of_kitti_tracking(shared_data):
    tuning = [f"{i:04d}" for i in range(10)]
    samples = collect_dimensions("kitti-tracking", shared_data / "kitti_tracking", sequences=tuning)
    counts = {name: len(d) for name, d in samples.dimensions.items()}
    assert counts == {"Car": 345, "Van": 30, "Truck": 11}
    estimates = estimate_priors(samples)
    assert [w.split(":")[0] for w in estimates.warnings] == ["Truck"]  # 11 < 20
    with (shared_data / "stats" / "kitti_dimension_stats_from_brought_data.csv").open() as handle:
        row = next(r for r in csv.DictReader(handle)
                   if r["sample"] == "kitti_tracking_train_per_track" and r["class"] == "Car")
    published_mean = np.array([float(row[k]) for k in ("mean_l", "mean_w", "mean_h")])
    published_std = np.array([float(row[k]) for k in ("std_l", "std_w", "std_h")])
    car = estimates.classes["Car"].gaussian
    # A geometric median of the tuning split against the mean of all 21 sequences: the subset's sampling
    # difference has sd ~ std sqrt(1/345 - 1/579) = 0.035 std (4 sd = 0.14 std), and median and mean of these
    # near-symmetric per-track distributions differ by about 0.1 std; 0.25 std bounds both.
    np.testing.assert_array_less(np.abs(car.mean - published_mean), 0.25 * published_std)
    # The robust spread is below the classical one (the tails are heavy) but of the same order.
    assert np.all(car.std < 1.2 * published_std) and np.all(car.std > 0.5 * published_std)


def test_command_line_recorded_in_the_sources():
    from toosicubix.priors.estimation import priors_command_line

    assert priors_command_line("kitti", "data/kitti") == "toosicubix priors --kitti data/kitti"
    assert (priors_command_line("kitti-tracking", "gt", ("Car", "Van"), ("0000", "0001", "0002", "0005"), "whitened")
            == "toosicubix priors --kitti-tracking gt --sequences 0000-0002,0005 --classes Car,Van "
               "--covariance whitened")
