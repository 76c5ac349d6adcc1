"""An agent that always outputs zero actions (the reference's `Dummy`): for view_motion and DoF-test envs.

No model and no optimiser; only the normalisers (so `save`/`load` still work). Zero is the env action
itself, not the centre of the action range.
"""

from __future__ import annotations

from typing import Any

import torch

from mimickit.learning.base_agent import BaseAgent


class DummyAgent(BaseAgent):
    def _build_model(self) -> None:
        pass

    def _build_optimizers(self) -> None:
        pass

    def _get_exp_buffer_length(self) -> int:
        return self.config.steps_per_iter

    def _decide_action(self, obs: torch.Tensor, info: dict[str, Any]) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """Zeros [N, A]."""
        return torch.zeros(obs.shape[0], self.get_action_size(), device=self._device), {}

    def _update_model(self) -> dict[str, float]:
        return {}
