"""The Siamese pair model: shared-satellite path, Algorithm 1 loss, configuration errors."""

from __future__ import annotations

import pytest
import torch
from scipy.spatial.transform import Rotation

from benchmark.models import ModelConfig, PoseModel, create_model
from benchmark.models.pair import IMAGENET_MEAN, IMAGENET_STD

SMALL = {"width": 0.25, "input_size": 32}


def small_model(**kwargs) -> PoseModel:
    torch.manual_seed(0)
    return create_model(**{**SMALL, **kwargs})


def batch(n: int = 6, n_sat: int = 2, size: int = 32, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    uav = torch.rand(n, 3, size, size, generator=g)
    sats = torch.rand(n_sat, 3, size, size, generator=g)
    ids = torch.arange(n) % n_sat
    R = torch.tensor(Rotation.random(n, random_state=seed).as_matrix(), dtype=torch.float32)
    T = torch.randn(n, 3, generator=g) * 50
    return uav, sats[ids], ids * 10 + 3, R, T


def assert_outputs_close(a, b, **tol):
    if isinstance(a, dict):
        for k in a:
            torch.testing.assert_close(a[k], b[k], **tol)
    else:
        torch.testing.assert_close(a, b, **tol)


class TestSharedSatellite:
    @pytest.mark.parametrize("training", [False, True])
    @pytest.mark.parametrize("variant", ["/", "a-f"])
    def test_shared_path_equals_plain_path(self, training, variant):
        model = small_model(variant=variant).train(training)
        uav, sat, ids, _, _ = batch()
        plain = model(uav, sat)
        shared = model(uav, sat, ids)
        tol = {"rtol": 1e-4, "atol": 1e-5}
        assert_outputs_close(plain.attitude, shared.attitude, **tol)
        assert_outputs_close(plain.translation, shared.translation, **tol)
        assert len(plain.aux_attitude) == len(shared.aux_attitude)
        for a, b in zip(plain.aux_attitude, shared.aux_attitude, strict=True):
            assert_outputs_close(a, b, **tol)

    def test_batchnorm_encoder_exact_in_eval_mode(self):
        model = small_model(variant="a-f", encoder_options={"norm": "batch"})
        uav, sat, ids, _, _ = batch()
        model.train()(uav, sat)  # move the running statistics away from their initial values
        model.eval()
        plain, shared = model(uav, sat), model(uav, sat, ids)
        torch.testing.assert_close(plain.attitude, shared.attitude, rtol=1e-4, atol=1e-5)

    def test_encodes_each_satellite_once(self):
        model = small_model(variant="/").eval()
        seen = []
        model.encoder.register_forward_hook(lambda m, i, o: seen.append(i[0].shape[0]))
        uav, sat, ids, _, _ = batch(n=6, n_sat=2)
        model(uav, sat, ids)
        assert seen == [6 + 2]

    def test_gradients_match(self):
        uav, sat, ids, R, T = batch()
        grads = []
        for sat_ids in (None, ids):
            model = small_model(variant="a-f").train()
            loss = model.loss(model(uav, sat, sat_ids), R, T)["total"]
            loss.backward()
            grads.append(model.encoder.stem[0][0].weight.grad.clone())
        torch.testing.assert_close(grads[0], grads[1], rtol=1e-3, atol=1e-5)

    def test_ids_that_do_not_identify_images(self):
        model = small_model(variant="/").eval()
        uav, sat, _, _, _ = batch(n=4, n_sat=4)
        with pytest.raises(ValueError, match="same id"):
            model(uav, sat, torch.zeros(4, dtype=torch.long))

    def test_bad_ids_shape(self):
        model = small_model(variant="/").eval()
        uav, sat, _, _, _ = batch(n=4)
        with pytest.raises(ValueError, match=r"sat_ids.*\(4,\)"):
            model(uav, sat, torch.zeros(3, dtype=torch.long))


class TestLoss:
    def test_algorithm1_assembly(self):
        model = small_model(variant="a-f", aux_weight=0.3).train()
        uav, sat, ids, R, T = batch()
        out = model(uav, sat, ids)
        terms = model.loss(out, R, T)
        assert set(terms) == {"total", "att", "tran", "att_final", "att_aux1", "att_aux2"}
        # Independent evaluation of each level through its own head.
        final = model.attitude_head.loss(out.attitude, R)
        aux = [
            h.loss(r, R) for h, r in zip(model.aux_attitude_heads, out.aux_attitude, strict=True)
        ]
        tran = model.translation_head.loss(out.translation, T)
        torch.testing.assert_close(terms["att"], final + 0.3 * aux[0] + 0.3 * aux[1])
        torch.testing.assert_close(terms["total"], terms["att"] + tran)
        assert all(t.dim() == 0 and torch.isfinite(t) for t in terms.values())

    @pytest.mark.parametrize("variant", ["/", "a"])
    def test_no_aux_terms_without_fusion(self, variant):
        model = small_model(variant=variant).train()
        uav, sat, ids, R, T = batch()
        out = model(uav, sat, ids)
        assert out.aux_attitude == ()
        assert set(model.loss(out, R, T)) == {"total", "att", "tran", "att_final"}

    def test_eval_mode_skips_aux(self):
        model = small_model(variant="a-f").eval()
        uav, sat, ids, _, _ = batch()
        out = model(uav, sat, ids)
        assert out.aux_attitude == ()
        R_hat, T_hat = model.decode(out)
        assert R_hat.shape == (6, 3, 3) and T_hat.shape == (6, 3)


class TestInputs:
    def test_convention_imagenet_normalisation_inside(self):
        model = small_model(variant="/", channels_last=False).eval()
        seen = []
        model.encoder.register_forward_hook(lambda m, i, o: seen.append(i[0]))
        mean_image = torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1).expand(1, 3, 32, 32)
        model(mean_image, mean_image + torch.tensor(IMAGENET_STD).view(1, 3, 1, 1))
        torch.testing.assert_close(seen[0][0], torch.zeros(3, 32, 32))
        torch.testing.assert_close(seen[0][1], torch.ones(3, 32, 32))

    def test_channels_last_same_result(self):
        uav, sat, ids, _, _ = batch()
        a = small_model(variant="a-f", channels_last=True).eval()(uav, sat, ids)
        b = small_model(variant="a-f", channels_last=False).eval()(uav, sat, ids)
        torch.testing.assert_close(a.attitude, b.attitude, rtol=1e-4, atol=1e-5)

    def test_float64(self):
        model = small_model(variant="a-f").double().train()
        uav, sat, ids, R, T = batch()
        terms = model.loss(model(uav.double(), sat.double(), ids), R.double(), T.double())
        assert terms["total"].dtype == torch.float64 and torch.isfinite(terms["total"])

    def test_mismatched_shapes(self):
        model = small_model(variant="/")
        with pytest.raises(ValueError, match="same shape"):
            model(torch.rand(2, 3, 32, 32), torch.rand(2, 3, 40, 40))


class TestConfiguration:
    @pytest.mark.parametrize(
        ("kwargs", "match"),
        [
            ({"attitude": "nope"}, "unknown attitude head 'nope'.*pd_re_net"),
            ({"attitude": "regression"}, "unknown attitude head 'regression'"),
            ({"translation": "pd_re_net"}, "unknown translation head 'pd_re_net'"),
            ({"encoder": "vgg"}, "unknown encoder 'vgg'.*googlenet"),
            ({"variant": "b"}, "unknown encoder variant 'b'"),
            ({"width": 0.0}, "width must be > 0 and finite, got 0.0"),
            ({"input_size": 24}, "input_size must be an int >= 32 px, got 24"),
            ({"attitude_options": {"kappa": 0.0}}, "kappa must be > 0.0, got 0.0"),
            ({"attitude_options": {"kapa": 5}}, "attitude head 'pd_re_net' takes no option 'kapa'"),
            ({"attitude_kwargs": {"kappa": 5}}, "attitude_kwargs is now called attitude_options"),
            ({"aux_weight": -1.0}, "aux_weight must be >= 0.0, got -1.0"),
            ({"colour": "red"}, "colour"),
            ({"satellite_input": "grey"}, "satellite_input must be one of .*got 'grey'"),
        ],
    )
    def test_bad_configuration_fails_at_construction(self, kwargs, match):
        with pytest.raises(ValueError, match=match):
            create_model(**{**SMALL, **kwargs})

    def test_config_round_trip_and_state_dict(self):
        model = small_model(variant="a-f", attitude="re_net_q")
        model.translation_head.set_statistics(torch.tensor([1.0, 2, 3]), torch.tensor([4.0, 5, 6]))
        config = ModelConfig(**model.config.to_dict())
        assert config == model.config and config.input_size == 32
        clone = create_model(config)
        clone.load_state_dict(model.state_dict())
        torch.testing.assert_close(clone.translation_head.std, torch.tensor([4.0, 5, 6]))
        uav, sat, ids, _, _ = batch()
        torch.testing.assert_close(
            model.eval()(uav, sat, ids).attitude, clone.eval()(uav, sat, ids).attitude
        )


class TestBlankSatellite:
    """The UAV-only control: the satellite input is replaced by constant grey inside the model."""

    @pytest.mark.parametrize("training", [False, True])
    @pytest.mark.parametrize("variant", ["/", "a-f"])
    def test_satellite_image_is_ignored(self, training, variant):
        model = small_model(variant=variant, satellite_input="blank").train(training)
        uav, sat, ids, _, _ = batch()
        other = torch.rand_like(sat)
        a, b = model(uav, sat, ids), model(uav, other, None)
        torch.testing.assert_close(a.attitude, b.attitude, rtol=1e-5, atol=1e-6)
        torch.testing.assert_close(a.translation, b.translation, rtol=1e-5, atol=1e-6)
        for x, y in zip(a.aux_attitude, b.aux_attitude, strict=True):
            torch.testing.assert_close(x, y, rtol=1e-5, atol=1e-6)

    @pytest.mark.parametrize("n", [1, 3, 8])
    def test_equals_normal_model_fed_grey(self, n):
        """Independent reference: the same weights with satellite_input='image' fed mid-grey."""
        blank = small_model(variant="/", satellite_input="blank").eval()
        plain = small_model(variant="/").eval()
        plain.load_state_dict(blank.state_dict())
        uav, sat, ids, _, _ = batch(n=n, n_sat=1)
        grey = torch.full_like(sat, 0.5)
        torch.testing.assert_close(
            blank(uav, sat, ids).attitude, plain(uav, grey).attitude, rtol=1e-4, atol=1e-5
        )

    def test_grey_encoded_once(self):
        model = small_model(variant="/", satellite_input="blank").eval()
        seen = []
        model.encoder.register_forward_hook(lambda m, i, o: seen.append(i[0].shape[0]))
        uav, sat, _, _, _ = batch(n=6, n_sat=3)
        model(uav, sat)
        assert seen == [6 + 1]

    def test_saved_in_config_and_default(self):
        model = small_model(variant="/", satellite_input="blank")
        assert model.config.to_dict()["satellite_input"] == "blank"
        clone = create_model(**model.config.to_dict())
        assert clone.satellite_input == "blank"
        assert small_model(variant="/").satellite_input == "image"

    def test_still_learns_from_the_uav_image(self):
        model = small_model(variant="/", satellite_input="blank").train()
        uav, sat, ids, R, T = batch()
        model.loss(model(uav, sat, ids), R, T)["total"].backward()
        grads = [p.grad for p in model.encoder.parameters() if p.grad is not None]
        assert grads and all(torch.isfinite(g).all() for g in grads)


class TestManualConstruction:
    def test_aux_head_count_must_match_levels(self):
        from benchmark.models import create_encoder, create_head

        enc = create_encoder("googlenet", variant="a-f", width=0.25, input_size=32)
        att = create_head("re_net_r", in_features=2 * enc.embedding_dims[-1])
        tran = create_head("regression", in_features=2 * enc.embedding_dims[-1])
        with pytest.raises(ValueError, match="2 auxiliary levels but 0"):
            PoseModel(enc, att, tran)

    def test_in_features_must_match_pair_embedding(self):
        from benchmark.models import create_encoder, create_head

        enc = create_encoder("googlenet", variant="/", width=0.25, input_size=32)
        att = create_head("re_net_r", in_features=enc.embedding_dims[-1])  # forgot the 2x
        tran = create_head("regression", in_features=2 * enc.embedding_dims[-1])
        with pytest.raises(
            ValueError, match="takes 512 features, the pair embedding has 2 \\* 512"
        ):
            PoseModel(enc, att, tran)
