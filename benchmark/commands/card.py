"""``overtakezoo card``: write the policy card (training hold, observation contract) of a policy file."""

from __future__ import annotations

from typing import Any

from overtakezoo.benchmark.commands._options import add_parser


def register(subparsers: Any) -> None:
    p = add_parser(
        subparsers,
        "card",
        "write the policy card of a policy file (its training hold)",
        "Write the policy card of a policy file you trained outside OvertakeZoo: its training hold, the\n"
        "core steps each decision was held in training (--action-repeat:\n"
        "your training env's action repeat / frame skip; 10 for overtakezoo/Overtake-v1 and the\n"
        "suite ids, the zoo's 1 s)\n"
        "and, with --suite, the observation contract (observation_size, observation_layout) of the\n"
        "suite it was trained on. It goes beside a Stable-Baselines3 .zip or a TorchScript file as\n"
        "<stem>.card.json, and into an ONNX file's metadata (key overtakezoo.card); written\n"
        "atomically. `eval --policy`, `decision-map --policy` and `submit` read it and hold each\n"
        "decision that long; the stored artifact of a submission keeps it, so `leaderboard --verify`\n"
        "re-runs with the same hold. Schema: benchmark/run/policy_card.schema.json. From Python:\n"
        "overtakezoo.benchmark.run.artifacts.write_card(path, action_repeat=10, suite='core-train').",
        [
            "overtakezoo card model.zip --action-repeat 10 --suite core-train   # writes model.card.json",
            "overtakezoo card policy.onnx --action-repeat 10                      # into the ONNX metadata",
            "overtakezoo card policy.pt --action-repeat 1 --name my-ppo --version 2",
        ],
    )
    p.add_argument("policy", metavar="POLICY", help="the policy file (.zip, TorchScript .pt, .onnx)")
    p.add_argument(
        "--action-repeat",
        type=int,
        required=True,
        metavar="N",
        help="the training hold: core steps each decision was held in training (1..1000)",
    )
    p.add_argument("--suite", help="the suite or training mixture it was trained on (records its observation contract)")
    p.add_argument("--name", help="the policy's name (file policies are named NAME-<sha256 prefix>)")
    p.add_argument("--version", help="the policy's version")
    p.set_defaults(handler=run)


def run(args: Any) -> int:
    from overtakezoo.benchmark.run.artifacts import write_card

    where = write_card(args.policy, args.action_repeat, args.suite, name=args.name, version=args.version)
    print(
        f"wrote the policy card of {args.policy} ({'into ' if where.suffix == '.onnx' else ''}{where}): decisions "
        f"held {args.action_repeat} core steps"
    )
    return 0
