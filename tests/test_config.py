"""benchmark.config: overrides, flatten, hash, YAML round trip, error messages."""

from __future__ import annotations

import dataclasses
import hashlib
import json
from typing import Any, ClassVar, Literal, Optional

import pytest

from benchmark.config import (
    ConfigError,
    apply_overrides,
    canonical_json,
    config_hash,
    flatten,
    from_dict,
    load_yaml,
    save_yaml,
    to_dict,
)


@dataclasses.dataclass(frozen=True)
class Optim:
    lr: float = 1e-3
    momentum: float = 0.9
    batch_size: int = 20
    nesterov: bool = False

    def __post_init__(self) -> None:
        if self.lr <= 0:
            raise ValueError(f"lr must be > 0, got {self.lr}")


@dataclasses.dataclass(frozen=True)
class Data:
    image_size: tuple[int, int] = (96, 96)
    splits: tuple[str, ...] = ("train", "val")
    limit: Optional[int] = None  # noqa: UP045 - the typing spelling must be supported too
    root: str | None = None
    kind: Literal["standard", "generalized"] = "standard"


@dataclasses.dataclass(frozen=True)
class Train:
    optim: Optim = Optim()
    data: Data = Data()
    seed: int = 0
    name: str = "pdre"


class TestApplyOverrides:
    def test_nested_types_converted(self):
        cfg = apply_overrides(
            Train(),
            [
                "optim.lr=0.01",
                "optim.batch_size=8",
                "optim.nesterov=true",
                "data.image_size=64,48",
                "data.splits=[train]",
                "data.limit=100",
                "data.kind=generalized",
                "seed=3",
                "name=a=b",  # only the first '=' splits
            ],
        )
        assert cfg.optim == Optim(lr=0.01, batch_size=8, nesterov=True)
        assert cfg.data.image_size == (64, 48) and cfg.data.splits == ("train",)
        assert cfg.data.limit == 100 and cfg.data.kind == "generalized"
        assert (cfg.seed, cfg.name) == (3, "a=b")
        assert type(cfg.optim.lr) is float and type(cfg.seed) is int

    def test_original_unchanged_and_frozen(self):
        base = Train()
        apply_overrides(base, ["optim.lr=0.5"])
        assert base.optim.lr == 1e-3

    def test_optional_none(self):
        cfg = apply_overrides(
            Train(data=Data(limit=5, root="/x")), ["data.limit=none", "data.root=null"]
        )
        assert cfg.data.limit is None and cfg.data.root is None

    def test_int_from_scientific_and_float_from_int(self):
        cfg = apply_overrides(Train(), ["optim.batch_size=1e2", "optim.lr=1"])
        assert cfg.optim.batch_size == 100 and cfg.optim.lr == 1.0

    @pytest.mark.parametrize(
        ("override", "pattern"),
        [
            ("optim.lrr=0.1", r"unknown config key 'optim\.lrr'.*optim\.lr"),
            ("optim.batch_size=2.5", r"optim\.batch_size='2\.5': expected int"),
            ("optim.nesterov=maybe", r"optim\.nesterov='maybe': expected bool"),
            ("optim.lr=fast", r"optim\.lr='fast': expected float"),
            ("data.image_size=1,2,3", r"data\.image_size='1,2,3': expected tuple\[int, int\]"),
            ("data.kind=odd", r"data\.kind='odd': expected one of 'standard', 'generalized'"),
            ("optim=3", r"optim='3': is a section \(Optim\)"),
            ("seed.x=1", r"'seed' is of type int, not a section"),
            ("seed", r"expected KEY=VALUE"),
            ("optim.lr=-1", r"optim\.lr=-1.*lr must be > 0"),
        ],
    )
    def test_errors_name_key_value_type(self, override, pattern):
        with pytest.raises(ConfigError, match=pattern):
            apply_overrides(Train(), [override])


class TestFlatten:
    def test_dotted_scalar_keys(self):
        flat = flatten(Train())
        assert flat["optim.lr"] == 1e-3 and flat["optim.batch_size"] == 20
        assert flat["data.image_size"] == "(96, 96)" and flat["data.limit"] is None
        assert set(flat) == {
            "optim.lr",
            "optim.momentum",
            "optim.batch_size",
            "optim.nesterov",
            "data.image_size",
            "data.splits",
            "data.limit",
            "data.root",
            "data.kind",
            "seed",
            "name",
        }
        assert all(not isinstance(v, (dict, list, tuple)) for v in flat.values())


class TestConfigHash:
    def test_stable_and_sensitive(self):
        h = config_hash(Train())
        # Independent reference: sha256 of the documented canonical payload.
        payload = f"{Train.__module__}.Train:" + json.dumps(
            to_dict(Train()), sort_keys=True, separators=(",", ":")
        )
        assert h == hashlib.sha256(payload.encode()).hexdigest()[:16]
        assert config_hash(Train()) == h
        assert config_hash(apply_overrides(Train(), ["seed=1"])) != h
        assert config_hash(apply_overrides(Train(), ["seed=0"])) == h
        assert canonical_json(Train()).startswith('{"data":')


class TestYaml:
    def test_round_trip(self, tmp_path):
        cfg = apply_overrides(Train(), ["data.image_size=32,32", "optim.lr=0.25", "data.limit=7"])
        path = save_yaml(cfg, tmp_path / "c.yaml", header="Table 1 (paper), standard test")
        assert path.read_text().startswith("# Table 1 (paper), standard test\n")
        assert load_yaml(path, Train) == cfg
        assert load_yaml(path)["optim"]["lr"] == 0.25  # raw mapping without a class

    def test_partial_file_keeps_defaults(self, tmp_path):
        (tmp_path / "p.yaml").write_text("optim:\n  lr: 0.1\n")
        assert load_yaml(tmp_path / "p.yaml", Train) == Train(optim=Optim(lr=0.1))

    @pytest.mark.parametrize(
        ("text", "pattern"),
        [
            ("optim:\n  lrr: 1\n", r"bad\.yaml: unknown config key 'optim\.lrr'"),
            ("optim:\n  batch_size: x\n", r"bad\.yaml: optim\.batch_size='x': expected int"),
            ("- 1\n- 2\n", r"bad\.yaml: expected a mapping"),
            ("optim: [1\n", r"bad\.yaml: not valid YAML"),
            ("optim:\n  lr: -2\n", r"bad\.yaml: optim: lr must be > 0"),
        ],
    )
    def test_errors_name_file_and_field(self, tmp_path, text, pattern):
        (tmp_path / "bad.yaml").write_text(text)
        with pytest.raises(ConfigError, match=pattern):
            load_yaml(tmp_path / "bad.yaml", Train)

    def test_missing_file(self, tmp_path):
        with pytest.raises(ConfigError, match=r"nope\.yaml: cannot read"):
            load_yaml(tmp_path / "nope.yaml", Train)

    def test_from_dict_nested_mapping(self):
        cfg = from_dict(Train, {"data": {"splits": ["a", "b"]}, "seed": 2})
        assert cfg.data.splits == ("a", "b") and cfg.seed == 2


@dataclasses.dataclass(frozen=True)
class Head:
    """A section with an options mapping whose owner types the values (like ModelConfig)."""

    MOVED: ClassVar[dict[str, str]] = {"kwargs": "options"}

    options: dict[str, Any] = dataclasses.field(default_factory=dict)

    def __post_init__(self) -> None:
        if "width" in self.options and not isinstance(self.options["width"], int | float):
            raise ValueError(f"options.width must be a number, got {self.options['width']!r}")


@dataclasses.dataclass(frozen=True)
class WithHead:
    MOVED: ClassVar[dict[str, str]] = {"loss.kappa": "head.options.kappa"}

    head: Head = Head()
    seed: int = 0


class TestMappingFields:
    def test_entry_set_by_key_as_yaml_scalar(self):
        cfg = apply_overrides(
            WithHead(),
            ["head.options.width=512", "head.options.rate=1e-3", "head.options.on=true",
             "head.options.norm=batch"],
        )  # fmt: skip
        assert cfg.head.options == {"width": 512, "rate": 0.001, "on": True, "norm": "batch"}

    def test_whole_mapping_from_a_flow_mapping(self):
        cfg = apply_overrides(WithHead(), ["head.options={width: 3, norm: group}"])
        assert cfg.head.options == {"width": 3, "norm": "group"}
        with pytest.raises(ConfigError, match=r"head\.options='5': expected .*mapping"):
            apply_overrides(WithHead(), ["head.options=5"])

    def test_owner_validation_applies(self):
        with pytest.raises(ConfigError, match=r"options\.width must be a number, got 'wide'"):
            apply_overrides(WithHead(), ["head.options.width=wide"])

    def test_yaml_round_trip(self, tmp_path):
        cfg = apply_overrides(WithHead(), ["head.options.width=2"])
        save_yaml(cfg, tmp_path / "c.yaml")
        assert load_yaml(tmp_path / "c.yaml", WithHead) == cfg
        assert flatten(cfg) == {"head.options.width": 2, "seed": 0}

    def test_moved_keys_say_where_they_live(self, tmp_path):
        with pytest.raises(ConfigError, match=r"'loss\.kappa' has moved: .*head\.options\.kappa"):
            apply_overrides(WithHead(), ["loss.kappa=5"])
        with pytest.raises(ConfigError, match=r"'head\.kwargs\.x' has moved: head\.kwargs -> h"):
            apply_overrides(WithHead(), ["head.kwargs.x=5"])
        (tmp_path / "old.yaml").write_text("loss:\n  kappa: 5\n")
        with pytest.raises(ConfigError, match=r"old\.yaml: config key 'loss' has moved"):
            load_yaml(tmp_path / "old.yaml", WithHead)


class TestOneKeyValueReader:
    """Issue 41: one KEY=VALUE reader for every ``--set`` (config overrides, model-info's model
    options, a reference's options): ``config.split_assignment``, and no other module splits an
    assignment itself."""

    def test_split_assignment(self):
        from benchmark.config import split_assignment

        assert split_assignment("optim.lr=0.01") == ("optim.lr", "0.01")
        assert split_assignment(" a.b = x=y") == ("a.b", " x=y")  # the first '=' splits
        for bad in ("seed", "=3", " =3"):
            with pytest.raises(ConfigError, match=r"expected KEY=VALUE, e\.g\. k=1"):
                split_assignment(bad, "k=1")

    def test_no_other_reader_in_the_library(self):
        import re
        from pathlib import Path

        root = Path(__file__).resolve().parents[1] / "benchmark"
        splitting = re.compile(r"""\.(partition|split)\(\s*["']=["']""")
        found = [
            str(path.relative_to(root))
            for path in sorted(root.rglob("*.py"))
            for line in path.read_text().splitlines()
            if splitting.search(line)
        ]
        assert found == ["config.py"], found  # the one in split_assignment
