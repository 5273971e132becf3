"""The prose of the generated ``leaderboards/README.md``: how to submit a policy, and the security model."""

# The one "Submit your policy" guide: the leaderboard page (generate.py, under GUIDE_HEADING) and the
# repository README (its "Submit your policy" section, verbatim: tests/docs/test_guide_submit.py) both show
# this text, and tests/docs/test_guide_submit.py (slow) runs its code blocks as written.
GUIDE_HEADING = "## Submit your policy"

GUIDE = """A row is a results file plus the policy that produced it, so anyone can re-run it:
`overtakezoo leaderboard --verify` runs every row's policy again and requires every per-scenario
value (outcome, times, aborts, ...) to equal the recorded one. A hand-edited results file, or one
whose policy does not reproduce it, is refused with one line naming the first scenario that differs.
Run these steps from the root of a clone of the repository (its `leaderboards/` is the one you add
your rows to); `tests/docs/test_guide_submit.py` runs them as written.

**1. Train** on the training world, each decision held as the zoo holds its own: one env step of
`overtakezoo/Overtake-v1` is one decision (0 follow, 1 overtake, 2 abort) held 1 s, 10 core steps,
on `table1-train` (the settings of `table1`, other scenarios; the same env as
`overtakezoo/table1-train-v2`). Any library works; with Stable-Baselines3's defaults
(`pip install 'overtakezoo[sb3]'`):

```python
import gymnasium as gym
import overtakezoo.envs  # registers overtakezoo/Overtake-v1: table1-train, decisions held 1 s
from stable_baselines3 import DQN

model = DQN("MlpPolicy", gym.make("overtakezoo/Overtake-v1"), seed=0)
model.learn(200_000)
model.save("my-dqn.zip")
```

Tune on `table1-train` (or another suite's `-train` id), never on the suites you submit to.
`overtakezoo/Overtake-v0` is the old default: table1-reactive's world at one core step (0.1 s) per
decision, on which an agent learns to always follow; Gymnasium warns that it is out of date.

**2. Write its policy card:** the hold it was trained with, so that `eval`, `submit` and `--verify`
hold each decision the same 10 core steps (a file without a card is held 1 core step, 0.1 s, and
acts ten times as often as it learned to):

```bash
overtakezoo card my-dqn.zip --action-repeat 10 --suite table1-train   # writes my-dqn.card.json
```

The card goes beside a `.zip` or TorchScript file (`my-dqn.card.json`) and inside an ONNX file. With
CleanRL, rsl-rl or your own torch code, export the network to ONNX (observations in, Q-values or
logits out; the mode is the argmax), e.g. `torch.onnx.export(net, (torch.zeros(1, D),),
"my-dqn.onnx", dynamic_axes={...}, dynamo=False)`, then card it the same way; a TorchScript file
also works and is converted to ONNX when you submit it. `overtakezoo train dqn --out runs/my-dqn`
(also `double-dqn`, `ppo`) writes `runs/my-dqn/dqn.npz` (numpy weights; the torch `dqn.pt` too)
with its card `dqn.json` beside it already: pass the `.npz` to `eval` and `submit`. A
`package.module:factory` policy works with `eval` but is not a file: export it to submit it.

**3. Evaluate** on each suite you want a row on (`overtakezoo suites` lists them):

```bash
overtakezoo eval --suite table1 --policy my-dqn.zip --out results/table1/my-dqn.json
```

The results file records the suite's sha256, the environment config's sha256, the simulator
version (`overtakezoo.envs.SIM_VERSION`), the OvertakeZoo version and commit, and your policy's
sha256. Trained as above (seed 0, 200,000 decisions: 28 CPU minutes, 70 wall minutes on a 2-core
machine shared with other jobs), this policy scored **table1 success 90.2 %, crash 9.8 %** (3000
scenarios; rule-fsm: 71 % / 29 %, the bar `tests/docs/test_guide_submit.py` holds it to).

**4. Submit** under a name of your own (the zoo's names, `overtakezoo zoo list`, are reserved):

```bash
overtakezoo submit results/table1/my-dqn.json --policy my-dqn.zip --name my-dqn
overtakezoo leaderboard --verify --only '*/my-dqn'   # every scenario of your rows re-runs exactly
overtakezoo leaderboard                              # regenerate the tables
```

`submit` refuses a results file measured on another suite file, environment config or simulator
version, a policy file whose sha256 differs from the one the results recorded, a reserved name,
and a name already on that suite's leaderboard unless you pass `--replace`. It converts your file
to a stored format (the leaderboard page's *Security model*), re-runs that stored form on every
scenario of the suite and files the row only if it gives your numbers exactly; the row's `decider`
block then describes the stored file. It is stored once, by content, as
`submissions/artifacts/<sha256>.npz` (with its model card `<sha256>.json`) or
`submissions/artifacts/<sha256>.onnx`, whatever number of suites you submit it to, and keeps the
card's hold for `--verify`. Keep it small (a few MB). `submit` and every `leaderboard` mode find
the leaderboard by one rule: `--root DIR` when given (for `leaderboard` it must exist; `submit
--root` to a new folder starts one there), else `./leaderboards` where it has `submissions/`, else
the `leaderboards/` of the checkout the package runs from; the default never creates a folder.

**5. Open a pull request** that contains exactly:

- `leaderboards/submissions/<suite>/my-dqn.json` for each suite (your results, with the
  `submission` block `submit` adds);
- `leaderboards/submissions/artifacts/<sha256>.npz` and `<sha256>.json`, or
  `leaderboards/submissions/artifacts/<sha256>.onnx` (your stored policy);
- the regenerated `leaderboards/README.md`, `leaderboards/index.json`, `leaderboards/<suite>.md`
  and `leaderboards/<suite>.png`.

CI checks that the tables are current and re-runs every scenario of your new rows; reviewers can
run `overtakezoo leaderboard --verify --only '*/my-dqn'` themselves.

A row goes *stale* (listed apart by name, under its suite's table) when the suite file, the
environment config or the simulator version changes; re-run step 3 and submit again with
`--replace`.
"""

SECURITY = """## Security model

A pull request to this leaderboard is untrusted input, and so is a policy file you download.
`overtakezoo leaderboard --verify` (run by CI and by reviewers) and `overtakezoo eval --policy FILE`
never run code from either:

- **Trusted:** the OvertakeZoo code of the base branch (simulator, zoo members and their shipped
  weights, verifier) and the suite files in `envs/suites/`. Everything else the pages show is
  re-derived: rows and cross-play matrices by `--verify` (below); a `seeds/` file speaks for the
  member its file name names, and its shipped seed must equal that member's verified rows;
  `reference/` figures cite their source and never rank.
- **Stored formats are data.** A row's policy is a built-in zoo member (by name, version and
  weights sha256) or an artifact in one of two formats: the project's `.npz` MLP with its model card
  (read with `numpy.load(allow_pickle=False)`) or one self-contained `.onnx` file (run by
  onnxruntime, external data inlined). No pickle, TorchScript or cloudpickle is stored or loaded:
  `submit` converts what you bring (an SB3 zip is read from its state dict with
  `torch.load(weights_only=True)` and its `data` as JSON; TorchScript is exported to ONNX inside
  the sandbox) and re-runs the converted file before filing the row.
- **Artifacts run in a box.** Every stored artifact (and every file given to `eval --policy`) acts in
  a child process: observations in, modes out, as `.npy` frames over pipes; an empty temporary
  working directory; CPU-time, memory and per-call wall-clock limits (the child is killed, not asked
  to stop); and, on Linux 5.13+, Landlock: no file can be written, created or removed outside its
  temporary directory and no TCP connection opened. A policy that crashes, hangs, returns NaN, a
  wrong shape or a mode outside {0, 1, 2} fails its row with one line naming the row, the scenario
  and the step.
- **Every label is re-derived.** The verifier does not believe a row's `decider` block: a built-in
  row must carry its member's current name, version, weights and `privileged` flag; an artifact
  row's block must equal what is derived from the artifact (kind from its content, `privileged`
  always false, the name the row's own). Built-in names are reserved in every case, file names are
  content hashes, and provenance (`git_commit`, `package.version`, `timing`) must match strict
  patterns. Every string the pages render is escaped (Markdown and HTML).
- **What CI verifies.** Every row that is new or changed against the pull request's base (a
  `git diff` of `submissions/`, untracked files included; a changed artifact counts for each row
  that uses it) is re-run on every scenario; with no base to compare with (a fresh clone of the
  branch under test, as CI runs) every row is. Every other row runs on `--sample K` scenarios drawn
  from a seed of fresh randomness, printed so that a failure replays with `--seed`: nobody can
  compute the draw before pushing. A row must have its suite's shape (every array, one value per
  scenario), and an artifact's policy must decide the same in batches of other sizes and orders. A
  new or changed stale row is refused; stale rows show no numbers, only their names. A cross-play
  matrix (`crossplay/<suite>.json`) is re-run the same way: its deciders' labels derived from the
  zoo, every pair of a new or changed matrix (or with no base), `--sample K` pairs of the others,
  and each pair's counts must equal the stored ones.
- **Draws nobody knew.** Every suite is public, so a policy could memorise its scenarios. `submit`
  also runs the policy on a *fresh draw* of the suite's distribution (a seed from fresh randomness)
  and records it in the row; the pages show its success and crash rates beside the public ones. A
  row whose fresh draw disagrees with its public scenarios (more than 5 standard errors apart) is
  flagged: listed apart, never ranked, out of the score. `--verify` re-runs the recorded draw and
  runs one of its own (a seed chosen when it runs), which must agree with the recorded one, so a
  recorded draw the policy was fit to is refused.
- **Regeneration owns only its files** (the list in `index.json`), refuses symlinks, FIFOs and
  devices anywhere under the leaderboard root, and `submit` holds a lock on `submissions/` while it
  files a row and prunes unused artifacts.
"""
