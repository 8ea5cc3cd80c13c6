"""A data-parallel training run for the distributed tests, launched by a real ``torchrun``:

    python -m torch.distributed.run --standalone --nproc_per_node 2 -m tests.helpers.ddp_train \\
        LOG CKPT REPORT EPOCHS_JSON [CONFIG_JSON]

Each rank trains the tiny test network (``tests.dsnet_core.train.test_loop.TINY``) on sequence 00
of LOG with the real :class:`Trainer` into CKPT (CONFIG_JSON: further :class:`TrainConfig` fields)
and writes ``REPORT/rank<r>.json``:

- ``steps``: after every optimiser step of the semantic and offset stages, a sha256 of the rank's
  parameters (identical on every rank if DDP keeps them in step);
- ``final``: a sha256 of the rank's parameters and buffers after the run;
- ``writes``: every write this process made under CKPT (files opened for writing, renames, new
  folders, removals), seen by a Python audit hook, independently of the trainer's own rank checks;

and ``REPORT/rank<r>_<stage><epoch>.safetensors``: the rank's state dict after each epoch's last
step (the weights a test compares with a reference computed by hand).
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
from pathlib import Path

import torch

WRITE_FLAGS = os.O_WRONLY | os.O_RDWR | os.O_CREAT | os.O_APPEND | os.O_TRUNC
PATH_EVENTS = {"os.rename": 2, "os.mkdir": 1, "os.remove": 1, "os.rmdir": 1, "shutil.rmtree": 1}
"""Audit events that change a folder → how many of their first arguments are paths."""


def record_writes(root: Path, writes: list[str]) -> None:
    """Append to ``writes`` every write-like audit event of this process on a path under ``root``."""
    prefix = str(root.resolve())

    def under(path: object) -> bool:
        if not isinstance(path, str | bytes | os.PathLike):
            return False
        return os.path.abspath(os.fsdecode(path)).startswith(prefix)

    def hook(event: str, args: tuple) -> None:
        if event == "open" and len(args) >= 3 and isinstance(args[2], int):
            if args[2] & WRITE_FLAGS and under(args[0]):
                writes.append(f"open {os.fsdecode(args[0])}")
        elif event in PATH_EVENTS and any(under(a) for a in args[: PATH_EVENTS[event]]):
            writes.append(f"{event} {os.fsdecode(args[0])}")

    sys.addaudithook(hook)


def digest(tensors: dict[str, torch.Tensor]) -> str:
    h = hashlib.sha256()
    for name, t in tensors.items():
        h.update(name.encode())
        h.update(t.detach().cpu().contiguous().numpy().tobytes())
    return h.hexdigest()


def main() -> None:
    torch.set_num_threads(1)
    log, ckpt, report = Path(sys.argv[1]), Path(sys.argv[2]), Path(sys.argv[3])
    epochs = json.loads(sys.argv[4])
    extra = json.loads(sys.argv[5]) if len(sys.argv) > 5 else {}
    rank = int(os.environ["RANK"])
    writes: list[str] = []
    record_writes(ckpt, writes)

    from safetensors.torch import save_file

    from dsnet_core.io.semantickitti import SemanticKittiReader
    from dsnet_core.train import distributed
    from dsnet_core.train.loop import TrainConfig, Trainer
    from tests.dsnet_core.train.test_loop import LM, TINY

    reader = SemanticKittiReader(log)
    cfg = TrainConfig(**{"stage": "all", "epochs": epochs, "augment": False, "lr": 0.01, **extra})
    trainer = Trainer(ckpt, TINY, reader, ["00"], reader, ["00"], LM, cfg)
    steps = []

    def on_step(stage: str, epoch: int, step: int, total: int, loss: float) -> None:
        steps.append([stage, epoch, step, digest(dict(trainer.model.named_parameters()))])
        if step == total:
            state = {k: v.detach().clone() for k, v in trainer.model.state_dict().items()}
            save_file(state, str(report / f"rank{rank}_{stage}{epoch}.safetensors"))

    trainer.run(on_step=on_step)
    final = digest(trainer.model.state_dict())
    distributed.teardown()
    out = {"steps": steps, "final": final, "writes": writes}
    (report / f"rank{rank}.json").write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
