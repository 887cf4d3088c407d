"""Head and encoder registries: names, discovery, entry points, errors."""

from __future__ import annotations

import importlib
import importlib.metadata
import sys
import textwrap
import types
from pathlib import Path

import pytest
import torch

from benchmark.models import (
    AttitudeHead,
    TranslationHead,
    create_encoder,
    create_head,
    get_head_class,
    head_kind,
    head_versions,
    list_encoders,
    list_heads,
    register_head,
)
from benchmark.models import registry as registry_module

PAPER_ATTITUDE = {
    "pd_re_net": "Pd/Re-Net",
    "pd_net_rv": "Pd-Net-Rv",
    "pd_net_e": "Pd-Net-E",
    "pd_net_q": "Pd-Net-Q",
    "re_net_r": "Re-Net-R",
    "re_net_rv": "Re-Net-Rv",
    "re_net_e": "Re-Net-E",
    "re_net_q": "Re-Net-Q",
}
PAPER_TRANSLATION = {"regression": "Pd/Re-Net", "re_net_t": "Re-Net-T"}


@pytest.fixture
def clean_registry(monkeypatch):
    """Let a test register heads without leaking them into other tests."""
    list_heads()  # make sure the built-in heads are discovered first
    monkeypatch.setattr(registry_module, "_HEADS", dict(registry_module._HEADS))
    return registry_module


class TestListHeads:
    def test_every_paper_head_is_registered(self):
        assert set(PAPER_ATTITUDE) <= set(list_heads("attitude"))
        assert set(PAPER_TRANSLATION) <= set(list_heads("translation"))

    def test_kind_filter_partitions(self):
        att, tran = set(list_heads("attitude")), set(list_heads("translation"))
        assert att.isdisjoint(tran)
        assert att | tran == set(list_heads())

    def test_paper_names(self):
        for name, paper in {**PAPER_ATTITUDE, **PAPER_TRANSLATION}.items():
            assert get_head_class(name).paper_name == paper

    def test_bad_kind(self):
        with pytest.raises(ValueError, match="rotation"):
            list_heads("rotation")


class TestCreateHead:
    def test_creates_the_registered_class(self):
        head = create_head("re_net_r", in_features=16)
        assert isinstance(head, AttitudeHead) and head.name == "re_net_r"
        assert head_kind(type(head)) == "attitude"

    def test_unknown_name_lists_known(self):
        with pytest.raises(ValueError, match=r"no_such_head.*pd_re_net"):
            create_head("no_such_head", in_features=16)

    def test_head_versions_are_positive_ints_and_check_the_kind(self):
        for att in list_heads("attitude"):
            versions = head_versions(att, "regression")
            assert set(versions) == {"attitude", "translation"}
            assert all(isinstance(v, int) and v >= 1 for v in versions.values())
        with pytest.raises(ValueError, match="unknown attitude head 'regression'"):
            head_versions("regression", "regression")

    def test_kind_mismatch(self):
        with pytest.raises(ValueError, match="unknown translation head 'pd_re_net'"):
            create_head("pd_re_net", "translation", in_features=16)

    @pytest.mark.parametrize("name", ["pd_re_net", "pd_net_rv", "pd_net_e", "pd_net_q", "re_net_t"])
    @pytest.mark.parametrize("kappa", [0.0, -1.0, float("nan")])
    def test_bad_kappa(self, name, kappa):
        with pytest.raises(ValueError, match=f"kappa.*{kappa}"):
            create_head(name, in_features=16, kappa=kappa)

    @pytest.mark.parametrize("in_features", [0, -3, 2.5, True])
    def test_bad_in_features(self, in_features):
        with pytest.raises(ValueError, match="in_features"):
            create_head("re_net_r", in_features=in_features)


class TestRegisterHead:
    def test_register_and_create(self, clean_registry):
        @register_head("toy_head")
        class Toy(AttitudeHead):
            paper_name = "Toy"

        assert "toy_head" in list_heads("attitude")
        assert isinstance(create_head("toy_head", in_features=3), Toy)

    def test_rejects_non_heads(self, clean_registry):
        with pytest.raises(TypeError, match="AttitudeHead or TranslationHead"):
            register_head("not_a_head")(torch.nn.Linear)

    def test_duplicate_name(self, clean_registry):
        with pytest.raises(ValueError, match="already registered"):

            @register_head("re_net_r")
            class Other(AttitudeHead):
                pass

    def test_bad_name(self):
        with pytest.raises(ValueError, match="identifier"):
            register_head("has space")


class TestEntryPoints:
    def test_external_head_class_is_registered(self, clean_registry, monkeypatch, tmp_path):
        (tmp_path / "ext_heads_pkg.py").write_text(
            textwrap.dedent(
                """
                from benchmark.models import TranslationHead

                class ExternalT(TranslationHead):
                    paper_name = "External"
                """
            )
        )
        monkeypatch.syspath_prepend(str(tmp_path))
        ep = importlib.metadata.EntryPoint(
            name="external_t", value="ext_heads_pkg:ExternalT", group="uavbench.heads"
        )

        def fake_entry_points(group=None, **_):
            return [ep] if group == "uavbench.heads" else []

        monkeypatch.setattr(importlib.metadata, "entry_points", fake_entry_points)
        monkeypatch.setitem(clean_registry._discovered, "heads", False)
        assert "external_t" in list_heads("translation")
        assert isinstance(create_head("external_t", in_features=4), TranslationHead)
        sys.modules.pop("ext_heads_pkg", None)

    def test_broken_entry_point_warns(self, clean_registry, monkeypatch):
        ep = importlib.metadata.EntryPoint(
            name="broken", value="no_such_module_xyz:Head", group="uavbench.heads"
        )
        monkeypatch.setattr(importlib.metadata, "entry_points", lambda group=None, **_: [ep])
        monkeypatch.setitem(clean_registry._discovered, "heads", False)
        with pytest.warns(UserWarning, match="broken"):
            names = list_heads()
        assert "pd_re_net" in names and "broken" not in names


class TestBuiltinHeadsEntryPoint:
    """The built-in heads reach the registry through this project's own entry point, so the
    registry never names ``baselines`` (imports point down)."""

    def test_the_project_declares_baselines_in_the_heads_group(self):
        eps = [
            ep
            for ep in importlib.metadata.entry_points(group="uavbench.heads")
            if ep.dist is not None and ep.dist.name == "uavbench"
        ]
        assert [(ep.name, ep.value) for ep in eps] == [("baselines", "baselines")]

    def test_every_head_file_is_registered(self):
        # One file per head: each module of baselines/ registers at least one head.
        import baselines

        files = {
            p.stem for p in Path(baselines.__path__[0]).glob("*.py") if not p.stem.startswith("_")
        }
        modules = {
            cls.__module__.removeprefix("baselines.") for cls in map(get_head_class, list_heads())
        }
        assert files <= modules

    def test_no_entry_point_is_a_clear_error(self, monkeypatch):
        monkeypatch.setattr(registry_module, "_HEADS", {})
        monkeypatch.setitem(registry_module._discovered, "heads", False)
        monkeypatch.setattr(importlib.metadata, "entry_points", lambda group=None, **_: [])
        with pytest.raises(RuntimeError, match=r"uavbench\.heads.*install the project"):
            list_heads()
        assert registry_module._discovered["heads"] is False  # the next lookup tries again

    @pytest.mark.parametrize("dist_name, raises", [("uavbench", True), ("other_pkg", False)])
    def test_own_broken_entry_point_raises_another_warns(
        self, clean_registry, monkeypatch, dist_name, raises
    ):
        # What the registry reads of an entry point: name, value, dist.name and load().
        def load():
            return importlib.import_module("no_such_module_xyz")

        ep = types.SimpleNamespace(
            name="broken",
            value="no_such_module_xyz",
            dist=types.SimpleNamespace(name=dist_name),
            load=load,
        )
        monkeypatch.setattr(importlib.metadata, "entry_points", lambda group=None, **_: [ep])
        monkeypatch.setitem(clean_registry._discovered, "heads", False)
        if raises:  # a head of this repository that cannot load is a bug here
            with pytest.raises(ModuleNotFoundError, match="no_such_module_xyz"):
                list_heads()
        else:  # another package's broken plug-in must not take the built-in heads down
            with pytest.warns(UserWarning, match="broken"):
                assert "pd_re_net" in list_heads()


class TestEncoderRegistry:
    def test_googlenet_registered(self):
        assert "googlenet" in list_encoders()

    def test_unknown_encoder(self):
        with pytest.raises(ValueError, match=r"resnet.*googlenet"):
            create_encoder("resnet")


class TestEntryPointErrors:
    def test_entry_point_that_is_not_a_head_warns(self, clean_registry, monkeypatch):
        ep = importlib.metadata.EntryPoint(
            name="linear", value="torch.nn:Linear", group="uavbench.heads"
        )
        monkeypatch.setattr(importlib.metadata, "entry_points", lambda group=None, **_: [ep])
        monkeypatch.setitem(clean_registry._discovered, "heads", False)
        with pytest.warns(UserWarning, match="linear"):
            names = list_heads()
        assert "linear" not in names and "pd_re_net" in names


class TestHeadOptions:
    def test_unknown_option_names_it_and_the_accepted_ones(self):
        with pytest.raises(
            TypeError, match=r"'re_net_r' does not take option.*kappa.*takes: hidden"
        ):
            create_head("re_net_r", in_features=8, kappa=10.0)
