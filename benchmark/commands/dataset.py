"""``overtakezoo dataset``: build offline-RL datasets (Minari format), list them, download published ones."""

from __future__ import annotations

import argparse
from typing import Any

from overtakezoo.benchmark.commands._options import add_parser


def register(subparsers: Any) -> None:
    p = add_parser(
        subparsers,
        "dataset",
        "build, list, download or pack offline-RL datasets (Minari)",
        "Offline-RL datasets in Minari's format (HDF5), stored where Minari looks: $MINARI_DATASETS_PATH,\n"
        "else $OVERTAKEZOO_HOME/datasets when that is set, else Minari's default ~/.minari/datasets;\n"
        "load them with minari.load_dataset(NAME).",
        [
            "overtakezoo dataset build --suite table1-train --decider rule-fsm --epsilon 0.1 "
            "--name overtakezoo/table1/rule-fsm-v0",
            "overtakezoo dataset list",
            "overtakezoo dataset download overtakezoo/table1/rule-fsm-v0",
            "overtakezoo dataset regenerate",
            "overtakezoo dataset pack overtakezoo/table1/rule-fsm-v0 --out rule-fsm-v0.tar.gz",
        ],
    )
    sub = p.add_subparsers(dest="action", metavar="ACTION")
    b = add_parser(
        sub,
        "build",
        "record a decider's transitions on a suite",
        "Run a decider (epsilon-random) on a suite and store every transition as a Minari dataset.",
        [
            "overtakezoo dataset build --suite table1-train --decider rule-fsm --name overtakezoo/table1/rule-fsm-v0",
            "overtakezoo dataset build --suite table1-train --decider always-overtake --count 100 "
            "--epsilon 0.3 --name overtakezoo/table1/overtake-v0",
        ],
    )
    b.add_argument("--suite", required=True, help="a suite name or .toml path")
    b.add_argument("--decider", required=True, help="a decider name from the zoo registry")
    b.add_argument("--name", required=True, help="dataset id, namespace/env/name-vN")
    b.add_argument("--epsilon", type=float, default=0.1, help="probability of a random mode per decision (0.1)")
    b.add_argument("--count", type=int, help="use only the first N scenarios of the suite")
    b.add_argument("--seed", type=int, default=0, help="seed of the exploration noise (0)")
    b.add_argument("--chunk-size", type=int, default=4096, help="scenarios stepped at once")
    b.add_argument("--overwrite", action="store_true", help="replace an existing dataset of that name")
    b.set_defaults(handler=run_build)
    ls = add_parser(
        sub,
        "list",
        "list the registry's datasets and the local ones",
        "List the published datasets of the package's registry (name, suite, deciders, episodes,\n"
        "steps, archive size, whether it is installed here) and the datasets in the local folder.",
        ["overtakezoo dataset list"],
    )
    ls.set_defaults(handler=run_list)
    d = add_parser(
        sub,
        "download",
        "fetch a published dataset (or rebuild it from its recipe)",
        "Download a dataset listed in the package's registry (`overtakezoo dataset list`) from its\n"
        "mirrors, in order (resumable, SHA-256 verified). When no mirror delivers it, the dataset is\n"
        "rebuilt locally from the registry's recipe and installed only if its content hash equals the\n"
        "registry's (--no-build: fail instead). Each step is printed.",
        [
            "overtakezoo dataset download overtakezoo/table1/rule-fsm-v0",
            "overtakezoo dataset download overtakezoo/table1/rule-fsm-v0 --no-build   # mirrors only",
        ],
    )
    d.add_argument("name", help="a dataset name from the registry")
    d.add_argument(
        "--no-build",
        dest="build",
        action="store_false",
        help="do not rebuild from the recipe when no mirror delivers the archive",
    )
    d.add_argument("--build", dest="build", action="store_true", help=argparse.SUPPRESS)  # the default now
    d.add_argument("--no-progress", action="store_true", help="no progress bar")
    d.set_defaults(handler=run_download)
    k = add_parser(
        sub,
        "pack",
        "write a local dataset as .tar.gz for publishing",
        "Pack a local dataset and print the registry entry (size, sha256) to publish it.",
        ["overtakezoo dataset pack overtakezoo/table1/rule-fsm-v0 --out rule-fsm-v0.tar.gz"],
    )
    k.add_argument("name")
    k.add_argument("--out", required=True, help="output .tar.gz")
    k.set_defaults(handler=run_pack)
    r = add_parser(
        sub,
        "regenerate",
        "rebuild the official datasets and rewrite the registry",
        "Build every dataset of the recipe table (benchmark/datasets/registry/recipes.toml), pack each archive\n"
        "for upload, and rewrite the registry with recipes, content hashes and archive hashes (atomically).",
        [
            "overtakezoo dataset regenerate",
            "overtakezoo dataset regenerate --archives dist/datasets --registry my-registry.json",
        ],
    )
    r.add_argument("--recipes", help="the recipe table (default: the package's registry/recipes.toml)")
    r.add_argument("--registry", help="registry file to write (default: $OVERTAKEZOO_REGISTRY or the package's)")
    r.add_argument("--archives", help="folder for the .tar.gz archives (default: <cache>/release/datasets-vN)")
    r.add_argument("--no-progress", action="store_true", help="no progress bars")
    r.set_defaults(handler=run_regenerate)
    p.set_defaults(handler=lambda args: (p.print_help(), 2)[1])


def run_build(args: Any) -> int:
    from overtakezoo.benchmark.datasets.record import build_dataset
    from overtakezoo.benchmark.datasets.store import datasets_dir
    from overtakezoo.benchmark.errors import UserError
    from overtakezoo.benchmark.run.policy import load_zoo
    from overtakezoo.envs.suites import load_suite

    if args.chunk_size < 1:
        raise UserError(f"--chunk-size {args.chunk_size}: must be >= 1")
    suite = load_suite(args.suite)
    decider = load_zoo(args.decider, suite.config)
    ds = build_dataset(
        args.name,
        suite,
        decider,
        epsilon=args.epsilon,
        count=args.count,
        seed=args.seed,
        chunk_size=args.chunk_size,
        overwrite=args.overwrite,
    )
    print(
        f"wrote dataset {args.name}: {ds.total_episodes} episodes, {ds.total_steps} steps in "
        f"{datasets_dir() / args.name}"
    )
    return 0


def run_list(args: Any) -> int:
    from overtakezoo.benchmark.datasets.registry import load_registry, registry_path
    from overtakezoo.benchmark.datasets.store import datasets_dir, list_datasets
    from overtakezoo.envs.model.outcomes import OUTCOME_NAMES

    found = list_datasets()
    registry = load_registry()
    print(f"published datasets (registry {registry_path()}; get one with `overtakezoo dataset download NAME`):")
    if not registry:
        print("  (none)")
    for name, e in sorted(registry.items()):
        recipe = e.get("recipe") or {}
        deciders = "+".join(p["decider"] for p in recipe.get("policies", [])) or "?"
        order = {name: i for i, name in enumerate(OUTCOME_NAMES)}  # success, crash, timeout, offroad
        shares = (
            "  ".join(
                f"{k} {100 * v:.1f} %"
                for k, v in sorted(e.get("outcomes", {}).items(), key=lambda kv: order.get(kv[0], 99))
            )
            or "outcomes ?"
        )
        print(
            f"  {name}  suite {recipe.get('suite', '?')}  {deciders}  episodes {e.get('episodes', '?')}  "
            f"steps {e.get('steps', '?')}  {shares}  {(e.get('size') or 0) / 1e6:.1f} MB  "
            f"{'installed' if name in found else 'not installed'}"
        )
    print(f"local datasets in {datasets_dir()}:")
    if not found:
        print("  (none; build one with `overtakezoo dataset build` or download one)")
    for name, meta in sorted(found.items()):
        print(
            f"  {name}  episodes {meta.get('total_episodes', '?')}  steps {meta.get('total_steps', '?')}  "
            f"{meta.get('dataset_size', '?')} MB  {meta.get('algorithm_name', '')}"
        )
    return 0


def run_download(args: Any) -> int:
    from overtakezoo.benchmark.datasets.fetch import download

    path = download(args.name, progress=not args.no_progress, build=args.build, say=print)
    print(f"installed {args.name} in {path}; load it with minari.load_dataset({args.name!r})" + _minari_hint())
    return 0


def _minari_hint() -> str:
    """What plain Minari code needs to find our datasets folder: nothing when it is Minari's own."""
    import os

    from overtakezoo.benchmark.datasets.store import datasets_dir, minari_default_dir

    if os.environ.get("MINARI_DATASETS_PATH") or datasets_dir() == minari_default_dir():
        return ""
    return f" (with MINARI_DATASETS_PATH={datasets_dir()}, as $OVERTAKEZOO_HOME moved the folder)"


def run_pack(args: Any) -> int:
    import json

    from overtakezoo.benchmark.datasets.store import pack

    out, size, sha = pack(args.name, args.out)
    print(f"wrote {out}; registry entry:")
    print(json.dumps({args.name: {"mirrors": ["https://.../" + out.name], "size": size, "sha256": sha}}, indent=1))
    return 0


def run_regenerate(args: Any) -> int:
    import time
    from pathlib import Path

    from overtakezoo.benchmark.datasets.recipes import RECIPES_FILE, regenerate
    from overtakezoo.benchmark.datasets.registry import registry_path
    from overtakezoo.benchmark.datasets.store import datasets_dir

    t0 = time.perf_counter()
    registry = Path(args.registry) if args.registry else registry_path()
    entries, archives = regenerate(
        Path(args.recipes) if args.recipes else RECIPES_FILE,
        registry,
        Path(args.archives) if args.archives else None,
        progress=not args.no_progress,
    )
    for name, e in entries.items():
        print(
            f"  {name}  {e['episodes']} episodes  {e['steps']} steps  content {e['content_sha256'][:16]}  "
            f"archive {e['size']} bytes"
        )
    print(
        f"wrote {registry}: {len(entries)} datasets (installed in {datasets_dir()}, archives to upload in "
        f"{archives}) in {time.perf_counter() - t0:.0f} s"
    )
    return 0
