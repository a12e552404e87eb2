"""PyTorch reference of SPAR (official module structure and state_dict key names).

SPAR's own modules: ``config`` (SparConfig, presets ``full`` and ``tiny``), ``transformer``
(the one block of every stack), ``spar`` (SPAR, make_checkpoint). Backbones (DINOv3, LSeg,
CLIP text) live in ``dino_v3``, ``lseg``, ``clip_text``, ``bpe`` and are imported lazily.
"""

from .config import SparConfig, full, tiny, get_config, PRESETS  # noqa: F401
from .transformer import Block, LayerNorm, RMSNorm, spar_block  # noqa: F401
from .spar import (  # noqa: F401
    SPAR, make_checkpoint, perturb_parameters, spar_own_state_dict, load_spar,
    plucker_rays, rot6d_to_mat, cam_info_to_se3, sincos_1d, sincos_2d, get_view_pairs,
)
