"""TinyMDM: the small motion diffusion model SMP uses as its motion prior (the reference's `learning/tinymdm`).

`modules.py` (the DiT block and its embeddings), `arch.py` (the denoisers), `ema.py`, `prior_config.py`
(the prior's yaml), `tinymdm_model.py` (`TinyMDMModel`: normaliser, loss, samplers, SDS loss; `load_prior`)
and `prior_dataset.py` (windows of disc obs from clips). The module and attribute names are the reference's,
so a prior trained by its `tools/diffusion_model/train_tinymdm.py` loads here. Needs the `smp` extra (diffusers).
"""
