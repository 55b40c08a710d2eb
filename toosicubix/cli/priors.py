"""``toosicubix priors``: thin over :mod:`toosicubix.priors.estimation`."""

from __future__ import annotations

from pathlib import Path

import click

from toosicubix.cli.options import (
    BadInput,
    GroundTruth,
    car_models_option,
    ground_truth_options,
    parse_classes,
    parse_sequences,
)


@click.command("priors")
@ground_truth_options("kitti", "kitti-tracking", "cityscapes", "apollocar3d")
@car_models_option
@click.option("-o", "--out", "out_path", type=click.Path(dir_okay=False, path_type=Path), required=True,
              help="Priors file to write (JSON); may be the --base file.")
@click.option("--classes", default=None,
              help="Comma-separated classes, case-insensitive [default: Car,Van,Truck for KITTI; every vehicle "
                   "prototype type found for Cityscapes; for ApolloCar3D the prototypes of its car-model types: Car "
                   "(hatchbacks), Sedan, SUV].")
@click.option("--sequences", default=None, help="KITTI tracking only: e.g. 0000-0009 or 0001,0005 (default: all).")
@click.option("--min-samples", type=click.IntRange(min=1), default=20, show_default=True,
              help="Classes with fewer samples are written but named in a warning; fewer than 2 are skipped.")
@click.option("--base", "base_path", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Start from this priors file: replace or add only the estimated classes, keep every other entry.")
@click.option("--covariance", "method", type=click.Choice(["paper", "whitened", "sample"]), default=None,
              help="paper: geometric median of the outer products divided by c (Gaussian-consistent for isotropic "
                   "spread); whitened: its fixed point in whitened coordinates (consistent for any Gaussian); "
                   "sample: arithmetic mean and sample covariance, for exact sizes without outliers, on which "
                   "medians collapse when one size repeats. [default: sample for ApolloCar3D, whose sizes are a "
                   "few dozen CAD models' extents; paper otherwise]")
@click.option("-q", "--quiet", is_flag=True, help="No summary or warnings on stderr.")
def priors_command(ground_truth: GroundTruth, car_models_path: Path | None, out_path: Path, classes: str | None,
                   sequences: str | None, min_samples: int, base_path: Path | None, method: str | None,
                   quiet: bool) -> None:
    """Estimate Gaussian size priors per class from ground-truth cuboids, as the paper does.

    Per class (KITTI type, Cityscapes 3D prototype type, ApolloCar3D prototype): mean = geometric median of
    the dimension vectors (dx, dy, dz) = (length, width, height); covariance = geometric median of the outer
    products (d - mean)(d - mean)^T divided by the Gaussian consistency factor c = 0.586. KITTI object labels
    count every object once, KITTI tracking every track once, Cityscapes 3D groups boxes by their prototype
    `type` name (e.g. 'Mid Size Car'), ApolloCar3D counts every labelled car once with its car model's
    extents, grouped by the prototype its car-model type gets on import (hatchback Car, saloon Sedan, SUV).
    Those extents repeat exactly (a few dozen CAD models), so for ApolloCar3D the mean and covariance are the
    samples' own (--covariance sample): medians would collapse onto the commonest model.
    Writes a priors file for `toosicubix fit --priors`; every entry records its data, its sample count and
    the method. Per-class counts and means go to stderr, with a warning naming every class with fewer than
    --min-samples samples.

    Exit code 0 on success, 2 for a missing folder, a malformed label file (file and line) or no estimable class.

    \b
    Example:
      toosicubix priors --kitti-tracking data/kitti_tracking --sequences 0000-0009 -o priors.json
      toosicubix priors --cityscapes gtBbox3d/train --base priors.json -o priors.json
      toosicubix priors --apollocar3d apollo_train.json --car-models car_models.json -o apollo-priors.json
    """
    from toosicubix.annotations.priors_file import load_priors_file
    from toosicubix.priors.estimation import (
        collect_dimensions,
        default_method,
        estimate_priors,
        priors_command_line,
        priors_document,
        write_priors_file,
    )

    if method is None:
        method = default_method(ground_truth.kind)
    if sequences is not None and ground_truth.kind != "kitti-tracking":
        raise click.UsageError("--sequences applies to --kitti-tracking only")
    sequence_names = parse_sequences(sequences)
    class_list = parse_classes(classes)
    command = priors_command_line(ground_truth.kind, ground_truth.root, class_list, sequence_names, method,
                                  car_models_path)
    base = load_priors_file(base_path) if base_path is not None else None
    samples = collect_dimensions(ground_truth.kind, ground_truth.root, class_list, sequence_names, car_models_path)
    estimates = estimate_priors(samples, min_samples=min_samples, method=method, command=command)  # type: ignore[arg-type]
    if not quiet:
        for warning in estimates.warnings:
            click.echo(f"warning: {warning}", err=True)
    if not estimates.classes:
        raise BadInput(f"no class gave a prior from {samples.describe()}: each needs at least 2 samples")
    document = priors_document(estimates, base)
    try:
        write_priors_file(document, out_path)
    except OSError as exc:
        raise BadInput(f"cannot write {out_path}: {exc.strerror or exc}") from None
    if not quiet:
        for name, prior in estimates.classes.items():
            g = prior.gaussian
            mean = ", ".join(f"{v:.3f}" for v in g.mean)
            std = ", ".join(f"{v:.3f}" for v in g.std)
            click.echo(f"{name}: n={g.n} {samples.unit}s, mean (dx, dy, dz) = ({mean}) m, sd = ({std}) m", err=True)
        kept = len(document.prototypes) - len(estimates.classes)
        base_note = f", kept {kept} other entries of {base_path}" if base_path is not None else ""
        click.echo(f"wrote {len(estimates.classes)} priors to {out_path}{base_note}", err=True)
