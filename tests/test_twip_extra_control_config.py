"""twip-extra-control's configuration (an experiment test: the library tests live in test_extra_control.py)."""

import pytest

from jaxdip import config as C


def test_variants_are_checked():
    import experiments.twip_extra_control as T

    cfg = C.load(T.TwipExtraControlConfig, sets=['variants=["k1=4; virtual=printed"]'])
    v = T.variant_config(cfg, cfg.variants[0])
    assert v.k1 == 4.0 and v.virtual == "printed" and v.k2 == cfg.k2 and v.variants == []
    for bad, why in (("n_hidden=3", "may set only"), ("k1=abc", "expected a number"), ("virtual=other", "one of"),
                     (" ; ", "at least one")):
        with pytest.raises(C.ConfigError, match=why):
            C.load(T.TwipExtraControlConfig, sets=[f'variants=["{bad}"]'])
