"""``slamcli vocab``: train and inspect bag-of-words vocabularies for place recognition."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated

import typer

from slamcli.cli import render
from slamcli.cli.common import boundary
from slamcli.errors import ConfigError, DataLossError, ExportError, InputError

vocab_app = typer.Typer(
    help="Train and inspect the ORB bag-of-words vocabularies used for loop closure.",
    no_args_is_help=True,
    rich_markup_mode="rich",
)

TRAIN_HELP = """Train an ORB vocabulary tree (DBoW2-style) on images and save it as one .npz.

INPUT is an image, a folder of PNG/JPEG images (searched recursively, in sorted order), a \
TUM RGB-D folder (its colour images) or an MCAP log (its image topic); give several to mix \
them. ORB features (8 levels, scale 1.2) of every --every-th image are clustered into a tree \
of --branching children per node and --levels levels (up to branching^levels words) with \
k-means++ seeding and k-majority iterations; each word gets an idf weight from the images it \
occurs in. Same inputs and --seed give a byte-identical file, written to a temporary name and \
renamed into place when complete.

Exit codes: 0 ok; 1 a missing or unreadable input, no features found, or --out exists \
without --force; 3 written, but some images in a folder could not be read (they are named).

Example: [bold]slamcli vocab train runs/synth_room --out runs/vocab.npz --levels 2 --force[/] \
(after the 'slamcli synth rgbd' example)
"""

INFO_HELP = """Show what a vocabulary file holds and what it was trained on.

FILE defaults to the vocabulary shipped with slamcli.

Example: [bold]slamcli vocab info runs/vocab.npz[/] (after the 'slamcli vocab train' example)
"""


def register(app: typer.Typer) -> None:
    app.add_typer(vocab_app, name="vocab", rich_help_panel="Data")


def _size(path: Path) -> str:
    size = path.stat().st_size
    return f"{size / 2**20:.2f} MiB ({size} bytes)"


@vocab_app.command("train", help=TRAIN_HELP)
@boundary
def train(
    inputs: Annotated[
        list[Path],
        typer.Argument(
            help="Images, image folders, TUM RGB-D folders or MCAP logs.",
            show_default=False,
        ),
    ],
    out: Annotated[
        Path,
        typer.Option("--out", "-o", help="Vocabulary file to write (.npz).", show_default=False),
    ],
    branching: Annotated[int, typer.Option("--branching", "-k", help="Children per node.")] = 10,
    levels: Annotated[int, typer.Option("--levels", "-L", help="Levels of the tree.")] = 4,
    features: Annotated[
        int, typer.Option("--features", min=1, help="ORB features per image.")
    ] = 1000,
    max_frames: Annotated[
        int | None,
        typer.Option(
            "--max-frames",
            min=1,
            help="At most this many images from each INPUT.",
            show_default=False,
        ),
    ] = None,
    every: Annotated[int, typer.Option("--every", min=1, help="Use every K-th image.")] = 1,
    seed: Annotated[int, typer.Option("--seed", help="Seeds the clustering.")] = 0,
    rgb_topic: Annotated[
        str | None,
        typer.Option(
            "--rgb-topic",
            help="Image topic of MCAP inputs (default: their only image topic).",
            show_default=False,
        ),
    ] = None,
    force: Annotated[bool, typer.Option("--force", help="Overwrite an existing --out.")] = False,
) -> None:
    """Train an ORB vocabulary tree on images and save it as one .npz."""
    from slamcli.atomic import check_writable_file
    from slamcli.vision.vocabulary import (
        MAX_NODES,
        extract_training_descriptors,
        save_vocabulary,
        train_vocabulary,
    )

    if branching < 2 or not 1 <= levels <= 8 or branching**levels > MAX_NODES:
        raise ConfigError(
            f"--branching {branching} --levels {levels}: expected branching >= 2, levels in "
            f"[1, 8] and at most {MAX_NODES} words (branching^levels)",
            hint="DBoW2 uses --branching 10 --levels 6; slamcli defaults to 10 and 4",
        )
    if out.exists() and not force:
        raise ExportError(f"{out}: already exists", hint="pass --force to overwrite it")
    check_writable_file(out)
    started = time.perf_counter()
    with render.progress("extracting ORB") as progress:
        images = extract_training_descriptors(
            inputs,
            features=features,
            every=every,
            max_frames=max_frames,
            rgb_topic=rgb_topic,
            progress=progress,
        )
    where = ", ".join(map(str, inputs))
    if not images.names:
        raise InputError(
            f"{where}: no 8-bit colour or grey image found"
            + (f" ({len(images.not_8bit)} 16-bit images, depth maps?)" if images.not_8bit else ""),
            hint="give the colour images: an rgb/ folder, a TUM RGB-D folder or image files",
        )
    if images.n_descriptors == 0:
        raise InputError(
            f"{', '.join(map(str, inputs))}: no ORB features found in {len(images.names)} image(s)",
            hint="give textured images; tiny or blank images have no corners",
        )
    with render.progress("clustering", levels) as progress:
        vocab = train_vocabulary(
            images.descriptors, branching=branching, levels=levels, seed=seed, progress=progress
        )
    save_vocabulary(vocab, out)
    rows = {
        "words": f"{vocab.n_words} (branching {branching}, {levels} levels)",
        "images": len(images.names),
        "descriptors": images.n_descriptors,
        "seed": seed,
        "file": _size(out),
        "time": f"{time.perf_counter() - started:.1f} s",
    }
    if images.not_8bit:
        rows["not used"] = f"{len(images.not_8bit)} image(s) that are not 8-bit (depth maps)"
    render.key_values("Vocabulary", rows)
    render.written([out])
    if images.unreadable:
        for line in images.unreadable[:5]:
            render.warn(line)
        raise DataLossError(
            f"{len(images.unreadable)} image(s) could not be read and were left out",
            hint="the vocabulary was written from the others",
        )


@vocab_app.command("info", help=INFO_HELP)
@boundary
def info(
    file: Annotated[
        Path | None,
        typer.Argument(help="A vocabulary .npz (default: the shipped one).", show_default=False),
    ] = None,
) -> None:
    """Show what a vocabulary file holds and what it was trained on."""
    from slamcli.vision.vocabulary import default_vocabulary_path, load_vocabulary

    path = default_vocabulary_path() if file is None else file
    vocab = load_vocabulary(path)
    idf = vocab.idf
    render.key_values(
        "Vocabulary",
        {
            "file": str(path) + (" (shipped default)" if file is None else ""),
            "branching": vocab.branching,
            "levels": vocab.levels,
            "words": vocab.n_words,
            "nodes": vocab.n_nodes,
            "trained on": f"{vocab.trained_images} images, "
            f"{vocab.trained_descriptors} descriptors (seed {vocab.seed})",
            "idf": f"{float(idf.min()):.2f} to {float(idf.max()):.2f}" if idf.size else "none",
            "size": _size(Path(path)),
        },
    )
