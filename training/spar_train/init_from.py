"""--init-from MODEL.spar: go on training from the weights of a packed model (spar-convert's
format, converter/FORMAT.md) instead of a fresh initialization: the shipped general model,
fitted further to a few rooms.

A packed file records where each tensor came from (its `conversion` metadata): most are the
checkpoint's tensors renamed ("kept"), rounded to fp16; the rest were folded by the converter
("folded"): a convolution and the BatchNorm after it into one convolution, DINOv3's k-bias mask
into its qkv bias. Both are undone here into a state with the same function: the folded
convolution's weight, the BatchNorm made the identity (weight 1, mean 0, variance 1 - eps) and
carrying the folded bias where the convolution has none. That identity holds with the
statistics frozen, so a run that starts from a packed model keeps its BatchNorms in eval mode
(`freeze_batch_norms`). Standard library, numpy and torch only."""
import json
from typing import Dict, List, Tuple

import numpy as np
import torch

from spar_convert.safetensors_file import SafetensorsFile


class InitFromError(ValueError):
    """A packed model that cannot start this run: one line naming the file and what is wrong."""


def _source_key(source: str) -> str:
    """'checkpoint.pt: cv_drp.x.weight' -> 'cv_drp.x.weight' (the checkpoint's own key)."""
    return source.split(": ", 1)[1]


def _tensor(f: SafetensorsFile, name: str) -> torch.Tensor:
    return torch.from_numpy(np.array(f[name], dtype=np.float32))


def unpack(path: str) -> Tuple[Dict[str, torch.Tensor], List[str]]:
    """The packed model at `path` as checkpoint-layout tensors (float32), and the keys it set
    to undo a fold (BatchNorms made the identity)."""
    try:
        f = SafetensorsFile(path)
    except Exception as e:  # the reader's errors are one line already
        raise InitFromError(f"--init-from {path}: {e}") from None
    with f:
        if "conversion" not in f.metadata:
            raise InitFromError(f"--init-from {path}: no conversion record (not a spar-convert file)")
        conv = json.loads(f.metadata["conversion"])
        eps = float(conv.get("bn_eps", 1e-5))
        out: Dict[str, torch.Tensor] = {}
        for name, source in conv.get("kept", {}).items():
            out[_source_key(source)] = _tensor(f, name)
        identities = []
        for name, sources in conv.get("folded", {}).items():
            keys = [_source_key(s) for s in sources]
            value = _tensor(f, name)
            bn = next((k[:-len("running_var")] for k in keys if k.endswith(".running_var")), None)
            if bn is None:                       # a mask folded into a bias: the bias as folded
                out[keys[0]] = value
                continue
            conv_weight = keys[0]
            conv_bias = conv_weight[:-len("weight")] + "bias"
            if name.endswith(".weight"):
                out[conv_weight] = value
            elif conv_bias in keys:              # the convolution has a bias: it takes the fold's
                out[conv_bias] = value
                out[bn + "bias"] = torch.zeros(value.shape)
            else:                                # it has none (created by the converter): the BN's
                out[bn + "bias"] = value
            # the BatchNorm's width: the folded bias's (a transposed convolution's weight has
            # its output channels second)
            n = f.info(name.rsplit(".", 1)[0] + ".bias").shape[0]
            out[bn + "weight"] = torch.ones(n)
            out[bn + "running_mean"] = torch.zeros(n)
            out[bn + "running_var"] = torch.full((n,), 1.0 - eps)
            identities.append(bn)
        return out, sorted(set(identities))


def load_into(model: torch.nn.Module, path: str, log=print) -> None:
    """Every tensor of the packed model at `path` into `model` (same configuration); what the
    file does not hold keeps the model's own values (tensors the forward never reads)."""
    tensors, identities = unpack(path)
    state = model.state_dict()
    wanted = {k: v for k, v in tensors.items() if not k.startswith("lseg_model.clip_pretrained.")}
    unknown = sorted(set(wanted) - set(state))
    if unknown:
        raise InitFromError(f"--init-from {path}: {len(unknown)} tensors this model does not have "
                            f"(another configuration?), first {unknown[0]}")
    for k, v in wanted.items():
        if tuple(state[k].shape) != tuple(v.shape):
            raise InitFromError(f"--init-from {path}: {k} is {tuple(v.shape)}, this model's "
                                f"{tuple(state[k].shape)} (another configuration?)")
        state[k] = v.to(state[k].dtype)
    model.load_state_dict(state)
    untouched = [k for k in state if k not in wanted and not k.endswith("num_batches_tracked")]
    log(f"init from {path}: {len(wanted)} tensors, {len(identities)} BatchNorms unfolded, "
        f"{len(untouched)} of the model's own kept ({', '.join(untouched[:3])}"
        f"{', ...' if len(untouched) > 3 else ''})")


def text_encoder_state(path: str) -> Dict[str, torch.Tensor]:
    """CLIP's text tower of the packed model (its keys without the checkpoint's prefix)."""
    tensors, _ = unpack(path)
    prefix = "lseg_model.clip_pretrained."
    return {k[len(prefix):]: v for k, v in tensors.items()
            if k.startswith(prefix) and k != prefix + "logit_scale"}


def freeze_batch_norms(model: torch.nn.Module) -> None:
    """Every BatchNorm in eval mode (statistics frozen): where they were unfolded as identities."""
    for m in model.modules():
        if isinstance(m, torch.nn.modules.batchnorm._BatchNorm):
            m.eval()
