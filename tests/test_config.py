"""The configuration: the study's defaults, CLI built from the dataclass, presets, validation,
json round trip."""

import dataclasses
import inspect
import json

import numpy as np
import pytest
import torch

from dqn_mine.config import (
    PRESETS,
    Config,
    ConfigError,
    build_parser,
    native_bf16,
    parse_args,
    resolve_actor_precision,
    resolve_device,
    to_argv,
)
from dqn_mine.replay import NStepWriter, PrioritizedReplay
from dqn_mine.replay.sampler import BETA0


def test_defaults_are_the_studys():
    c = Config()
    assert (c.actors, c.epsilon, c.epsilon_schedule, c.lr, c.batch_size, c.gamma, c.n_step) == \
        (7, 0.01, "fixed", 3e-5, 32, 0.99, 6)
    assert (c.replay_capacity, c.zeta, BETA0) == (1_048_576, 0.6, 0.4)
    for eta_taker in (PrioritizedReplay, NStepWriter):   # eta: the study's, where it is added
        assert inspect.signature(eta_taker).parameters["eta"].default == 1e-5
    assert (c.history_len, c.frame_stack, c.publish_interval, c.prefill, c.task) == \
        (20, 1, 500, 50_000, "two-room")
    assert parse_args([]) == c.validate()


def test_every_field_has_a_flag_with_one_line_help():
    helptext = build_parser().format_help()
    for f in dataclasses.fields(Config):
        assert f.metadata["help"] and "\n" not in f.metadata["help"]
        assert f"--{f.name.replace('_', '-')}" in helptext


def test_frozen():
    with pytest.raises(dataclasses.FrozenInstanceError):
        Config().actors = 3


def test_flag_types():
    c = parse_args(["--unstick", "2", "--rooms-schedule", "3", "4", "--max-episode-steps", "300",
                    "--replay-ratio", "0.05", "--demos-from", "none", "--task", "rooms"])
    assert c.unstick == 2 and c.rooms_schedule == (3, 4) and c.max_episode_steps == 300
    assert c.replay_ratio == 0.05 and c.demos_from is None
    assert parse_args(["--no-serial"]).serial is False and parse_args(["--serial"]).serial


def test_cli_round_trip():
    c = Config(task="rooms", num_rooms=4, room_size=12.5, max_episode_steps=123, unstick=2,
               lr=1 / 3, rooms_schedule=(4, 5), replay_ratio=0.02, view="clear",
               precision="float32", run_dir="runs/x y", preset="smoke", seed=9, serial=True,
               eval_num_rooms=5)
    assert parse_args(to_argv(c)) == c
    assert parse_args(to_argv(Config())) == Config()


def test_preset_precedence_defaults_preset_flags():
    smoke = parse_args(["--preset", "smoke"])
    for name, value in PRESETS["smoke"].items():
        assert getattr(smoke, name) == value
    assert smoke.gamma == Config().gamma  # not in the preset: default
    c = parse_args(["--lr", "0.5", "--preset", "smoke"])  # flag order does not matter
    assert c.lr == 0.5 and c.actors == PRESETS["smoke"]["actors"] and c.preset == "smoke"
    # an explicit flag equal to the default still beats the preset
    assert parse_args(["--preset", "smoke", "--actors", "7"]).actors == 7


BAD = [
    (["--updates", "0"], "--updates must be at least 1"),
    (["--actors", "0"], "--actors"),
    (["--envs-per-actor", "0"], "--envs-per-actor"),
    (["--n-step", "0"], "--n-step"),
    (["--batch-size", "0"], "--batch-size"),
    (["--replay-capacity", "16"], "smaller than --batch-size"),
    (["--replay-capacity", "64", "--batch-size", "8", "--actors", "10"], "slots"),
    (["--replay-capacity", "64", "--batch-size", "64", "--actors", "1"], "sampleable"),
    (["--replay-capacity", "1000", "--batch-size", "512", "--actors", "7"], "sampleable"),
    (["--n-step", "300"], "at most 254"),
    (["--room-size", "inf"], "--room-size"),
    (["--task", "two-room", "--num-rooms", "5"], "--num-rooms"),
    (["--task", "rooms", "--num-rooms", "17"], "--num-rooms"),
    (["--task", "rooms", "--curriculum", "schedule", "--rooms-schedule", "3", "4", "40"],
     "--rooms-schedule"),
    (["--task", "three-room", "--curriculum", "adaptive", "--placement", "any-room"],
     "--placement fixed"),
    (["--task", "cave"], "invalid choice"),
    (["--device", "tpu"], "invalid choice"),
    (["--precision", "float16"], "invalid choice"),
    (["--view", "wide"], "invalid choice"),
    (["--placement", "anywhere"], "invalid choice"),
    (["--preset", "huge"], "unknown preset"),
    (["--actors", "two"], "invalid int"),
    (["--zeta", "-0.1"], "--zeta"),
    (["--gamma", "0"], "--gamma"),
    (["--gamma", "1.01"], "--gamma"),
    (["--epsilon", "2"], "--epsilon"),
    (["--unstick", "-1"], "--unstick"),
    (["--lr", "0"], "--lr"),
    (["--frame-stack", "0"], "--frame-stack"),
    (["--history-len", "-1"], "--history-len"),
    (["--target-update-interval", "0"], "--target-update-interval"),
    (["--publish-interval", "0"], "--publish-interval"),
    (["--replay-ratio", "0"], "--replay-ratio"),
    (["--room-size", "0"], "--room-size"),
    (["--max-episode-steps", "0"], "--max-episode-steps"),
    (["--curriculum", "uniform"], "--curriculum"),
    (["--zeta", "-1"], "--zeta"),
    (["--task", "rooms", "--num-rooms", "1"], "--num-rooms"),
    (["--curriculum", "adaptive", "--task", "one-room"], "three-room"),
    (["--curriculum", "adaptive", "--task", "two-room"], "needs --task three-room"),
    (["--curriculum", "boulders", "--task", "three-room"], "--curriculum"),
    (["--curriculum", "schedule", "--task", "rooms", "--rooms-schedule", "1", "3"],
     "--rooms-schedule"),
    (["--prefill", "-1"], "--prefill"),
    (["--minutes", "0"], "--minutes"),
    (["--task", "three-room", "--curriculum-dr", "0.5"], "--curriculum-dr"),
    (["--preset", "cpu-three-room", "--curriculum-dr", "1.0"], "--curriculum-dr"),
    (["--exploration", "boltzmann"], "--exploration"),
    (["--task", "two-room", "--eval-num-rooms", "5"], "--eval-num-rooms"),
    (["--task", "rooms", "--eval-num-rooms", "13"], "--eval-num-rooms"),
    (["--bogus", "1"], "unrecognized"),
    (["--resume", "/nonexistent/run"], "--resume"),
]


@pytest.mark.parametrize("argv,fragment", BAD, ids=[" ".join(a) for a, _ in BAD])
def test_bad_flags_give_one_line_errors(argv, fragment):
    with pytest.raises(ConfigError) as info:
        parse_args(argv)
    message = str(info.value)
    assert fragment in message and "\n" not in message


def test_json_round_trip(tmp_path):
    c = Config(lr=1 / 3, rooms_schedule=(3, 5), max_episode_steps=None, replay_ratio=0.1 + 0.2,
               view="clear", run_dir=str(tmp_path), zeta=0.0)
    c.to_json(tmp_path / "config.json")
    back = Config.from_json(tmp_path / "config.json")
    assert back == c and isinstance(back.rooms_schedule, tuple)


def test_config_json_states_what_differs_from_the_preset(tmp_path):
    c = parse_args(["--preset", "cpu", "--lr", "3e-4", "--replay-ratio", "0.1",
                    "--actors", "2", "--run-dir", str(tmp_path)])
    c.to_json(tmp_path / "config.json")
    saved = json.loads((tmp_path / "config.json").read_text())
    # --actors 2 is the cpu preset's own value, so it is no difference.
    assert saved["preset"] == "cpu"
    assert saved["differs_from_preset"] == {"lr": 3e-4, "replay_ratio": 0.1}
    assert Config.from_json(tmp_path / "config.json") == c
    assert parse_args([]).preset_differences() == {}


def test_a_run_saved_before_the_prefill_explorer_existed_resumes_with_the_agents_prefill(tmp_path):
    c = Config()
    assert c.prefill_explorer == "bump-and-press"       # the default now
    data = json.loads(json.dumps(c.to_dict()))
    del data["prefill_explorer"]                         # as older run folders wrote it
    (tmp_path / "config.json").write_text(json.dumps(data))
    assert Config.from_json(tmp_path / "config.json").prefill_explorer == "agent"
    for preset in ("smoke", "cpu", "cpu-three-room"):    # measured with the agent's pre-fill
        assert parse_args(["--preset", preset]).prefill_explorer == "agent"


def test_every_preset_says_why_in_help():
    from dqn_mine.config import PRESET_REASONS

    assert list(PRESET_REASONS) == list(PRESETS)
    helptext = build_parser().format_help()
    assert all(f"  {name}:" in helptext for name in PRESETS)


def test_saved_configs_carry_their_version_and_older_ones_migrate(tmp_path):
    from dqn_mine.config import CONFIG_VERSION, VERSION_KEY

    c = Config(seed=3)
    c.to_json(tmp_path / "config.json")
    assert json.loads((tmp_path / "config.json").read_text())[VERSION_KEY] == CONFIG_VERSION
    v1 = {**c.to_dict(), "per": False, "curriculum_steps": None, "episode_order": "ended",
          "curriculum_review_pick": "uniform", "init_priority": "actor",
          "target_update_early": None, "target_update_early_phase": 12}
    (tmp_path / "v1.json").write_text(json.dumps(v1))
    assert Config.from_json(tmp_path / "v1.json") == dataclasses.replace(c, zeta=0.0)
    for name, value in [("curriculum_steps", 500), ("target_update_early", 250),
                        ("curriculum_review_pick", "nearest"), ("curriculum", "uniform")]:
        (tmp_path / "v1.json").write_text(json.dumps({**v1, name: value}))
        with pytest.raises(ConfigError, match=f"version 1 config with {name} = "):
            Config.from_json(tmp_path / "v1.json")
    (tmp_path / "v9.json").write_text(json.dumps({**c.to_dict(), VERSION_KEY: 9}))
    with pytest.raises(ConfigError, match="config version 9"):
        Config.from_json(tmp_path / "v9.json")
    # a version 2 config keeps today's defaults for what it lacks
    v2 = {k: v for k, v in c.saved_dict().items() if k != "prefill_explorer"}
    (tmp_path / "v2.json").write_text(json.dumps(v2))
    assert Config.from_json(tmp_path / "v2.json").prefill_explorer == "bump-and-press"


def test_version_2_configs_migrate_to_merged_and_removed_settings(tmp_path):
    """Version 3 merged the look settings into --view, the two precisions into one, unstick
    and its cycle into one count, and made constants of settings no preset changed; a version 2
    run with another value fails in one line."""
    from dqn_mine.config import VERSION_KEY

    v2 = {**{k: v for k, v in PRESETS["cpu"].items() if k != "unstick"},
          VERSION_KEY: 2, "preset": "cpu-three-room", "task": "three-room",
          "updates": 600_000, "camera_pitch": 15.0,
          "room_colours": True, "held_on_top": True, "unstick": True, "unstick_cycle": 2,
          "eval_held": True, "eval_unstick": True, "eval_epsilon": 0.01, "learner_queue": 4,
          "learner_precision": "auto", "actor_precision": "float32", "progress": True,
          "ez_mu": 2.0, "eta": 1e-5, "beta0": 0.4, "max_grad_norm": 40.0}
    (tmp_path / "v2.json").write_text(json.dumps(v2))
    assert Config.from_json(tmp_path / "v2.json") == \
        parse_args(["--preset", "cpu-three-room", "--precision", "float32"])
    for name, value in [("camera_pitch", 10.0), ("eta", 1e-3), ("ez_mu", 3.0),
                        ("max_grad_norm", None)]:
        (tmp_path / "v2.json").write_text(json.dumps({**v2, name: value}))
        with pytest.raises(ConfigError, match=f"version 2 config with .*{name}") as info:
            Config.from_json(tmp_path / "v2.json")
        assert "\n" not in str(info.value)
    (tmp_path / "v2.json").write_text(json.dumps({**v2, "unstick": False}))
    assert Config.from_json(tmp_path / "v2.json").unstick == 0


@pytest.mark.parametrize("saved,fragment", [
    ({"config_version": 2, "curriculum": "adaptive", "boulder_phases": True}, "'boulders'"),
    ({"config_version": 3, "curriculum": "boulders"}, "'boulders'"),
    ({"config_version": 3, "curriculum": "adaptive", "curriculum_review_unit": "steps"},
     "version 3 config with curriculum_review_unit"),
])
def test_runs_of_the_removed_phase_table_cannot_be_continued(tmp_path, saved, fragment):
    """Version 4 removed three-room's 23-phase table and its review unit: such a run fails in
    one line; one that reviewed by episodes (the unit's neutral value) loads."""
    base = {"task": "three-room", "curriculum_review": 0.5}
    (tmp_path / "old.json").write_text(json.dumps({**base, **saved}))
    with pytest.raises(ConfigError, match=fragment) as info:
        Config.from_json(tmp_path / "old.json")
    assert "\n" not in str(info.value)
    neutral = {**base, "config_version": 3, "curriculum": "adaptive",
               "curriculum_review_unit": "episodes"}
    (tmp_path / "old.json").write_text(json.dumps(neutral))
    assert Config.from_json(tmp_path / "old.json").curriculum_review == 0.5


@pytest.mark.parametrize("content,fragment", [
    ("{not json", "corrupt"), ('{"actors": 3, "warp": 9}', "unknown settings warp"),
    ("[1, 2]", "json object"), ('{"actors": "7"}', "actors = '7'"),
    ('{"rooms_schedule": [3, "x"]}', "rooms_schedule"), ('{"lr": null}', "lr = None"),
    (b"\xff\xfe\x00", "corrupt"), (None, "no config file")])
def test_bad_json_files(tmp_path, content, fragment):
    path = tmp_path / "config.json"
    if isinstance(content, bytes):
        path.write_bytes(content)
    elif content is not None:
        path.write_text(content)
    with pytest.raises(ConfigError) as info:
        Config.from_json(path)
    assert fragment in str(info.value) and "\n" not in str(info.value)


def test_resume_loads_the_saved_config_and_flags_still_win(tmp_path):
    saved = parse_args(["--preset", "smoke", "--seed", "4"]).with_run_dir()
    saved.to_json(tmp_path / "config.json")
    c = parse_args(["--resume", str(tmp_path), "--updates", "99"])
    assert c == dataclasses.replace(saved, updates=99, resume=str(tmp_path), run_dir=str(tmp_path))
    with pytest.raises(ConfigError, match="network's shape"):
        parse_args(["--resume", str(tmp_path), "--history-len", "10"])
    assert parse_args(["--resume", str(tmp_path), "--history-len", str(saved.history_len)])
    (tmp_path / "config.json").write_text("{")
    with pytest.raises(ConfigError, match="--resume"):
        parse_args(["--resume", str(tmp_path)])


def test_live_transitions_bound_is_what_a_full_replay_holds():
    """min_live_transitions against a real writer: fill one stream's ring well past a lap and
    count the transitions the sampler could draw after every step."""
    from dqn_mine.config import min_live_transitions
    from dqn_mine.replay import NStepWriter, PrioritizedReplay, ReplayStorage
    from dqn_mine.shared import SharedBlocks
    from dqn_mine.system.layout import replay_layout

    cfg = parse_args(["--actors", "1", "--replay-capacity", "200", "--batch-size", "8"])
    layout = replay_layout(cfg)
    with SharedBlocks.create(layout.block_specs()) as blocks:
        storage = ReplayStorage(layout, blocks)
        replay = PrioritizedReplay(storage)
        writer = NStepWriter(storage, stream=0)
        frame = np.zeros((3, 44, 76), np.uint8)
        writer.begin_episode(frame, False)
        sizes = []
        for _ in range(700):
            writer.append(np.zeros(6, np.float32), 0, 0.0, frame, False, False, False)
            replay.ingest()
            sizes.append(len(replay))
    lowest = min(sizes[300:])                        # after the first lap
    assert 0 < min_live_transitions(cfg) <= lowest < 200


def test_run_dir_name():
    c = Config(task="one-room", preset="smoke", seed=3).with_run_dir(now=0)
    assert c.run_dir.startswith("runs/one-room__smoke__3__") and len(c.run_dir.split("__")) == 4
    assert Config(run_dir="x").with_run_dir().run_dir == "x"


def test_resolve_device():
    assert resolve_device("cpu") == torch.device("cpu")
    if torch.cuda.is_available():
        assert resolve_device("auto").type == "cuda"
    else:
        assert resolve_device("auto").type == "cpu"
        with pytest.raises(ConfigError, match="no CUDA"):
            resolve_device("cuda")


def test_resolve_actor_precision(tmp_path):
    assert resolve_actor_precision("float32", 32) == torch.float32
    assert resolve_actor_precision("bfloat16", 1) == torch.bfloat16    # asked for: always
    assert resolve_actor_precision("auto", 4) == torch.float32        # too few frames per forward
    assert resolve_actor_precision("auto", 8) == (torch.bfloat16 if native_bf16()
                                                  else torch.float32)
    cpu = tmp_path / "cpuinfo"
    cpu.write_text("flags\t\t: fpu sse2 avx2 avx512f avx512bw\n")   # AVX-512 without BF16
    assert not native_bf16(str(cpu))
    cpu.write_text("flags\t\t: fpu sse2 avx2 avx512f avx512_bf16 amx_tile\n")
    assert native_bf16(str(cpu)) == torch.backends.mkldnn.is_available()
    assert not native_bf16(str(tmp_path / "missing"))


def test_learner_threads():
    from dqn_mine.config import learner_threads
    assert learner_threads(Config(actors=2), cores=2) == 1
    assert learner_threads(Config(actors=7), cores=16) == 9
    assert learner_threads(Config(actors=7, eval_every=10_000), cores=16) == 8


def test_help_is_grouped_by_section():
    from dqn_mine.config import build_parser

    text = build_parser().format_help()
    heads = ["task:", "curriculum:", "actors and exploration:", "learner:", "network:", "replay:",
             "demonstrations:", "evaluation:", "run:"]
    lines = text.splitlines()
    at = [lines.index(h) for h in heads]
    assert at == sorted(at)                                   # in this order
    section_of = lambda flag: max(h for h in at if h < next(  # noqa: E731
        i for i, line in enumerate(lines) if line.strip().startswith(flag)))
    assert lines[section_of("--lr")] == "learner:"
    assert lines[section_of("--zeta")] == "replay:"
    assert lines[section_of("--epsilon ")] == "actors and exploration:"
    assert lines[section_of("--backward-step")] == "curriculum:"
    assert lines[section_of("--demo-margin")] == "demonstrations:"
    assert lines[section_of("--resume")] == "run:"


def test_progress_bar_shows_phase_only_with_a_curriculum():
    from dqn_mine.metrics import progress_postfix

    row = {"episode_return": 0.25, "eval_return": float("nan"), "phase": 0, "loss": 1e-4}
    assert progress_postfix(row) == {"ret": "0.25", "loss": "0.0001"}
    assert progress_postfix({**row, "phase": 3})["phase"] == "3"
    assert progress_postfix({**row, "rewarded_episodes": 12345})["rewarded"] == "12345"


def test_a_log_file_gets_the_bars_figures_as_one_line_per_row():
    from dqn_mine.metrics import progress_line

    row = {"update": 1500, "wall_time": 90.0, "episode_return": 0.25, "loss": 1e-4,
           "eval_return": float("nan"), "phase": 0}
    assert progress_line(row, 300_000) == \
        "train: 1,500/300,000 updates, 1.5 min | ret=0.25 loss=0.0001"
