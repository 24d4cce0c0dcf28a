"""TacGNN's message-passing layer: an EdgeConv with max aggregation on K neighbours per node."""

from __future__ import annotations

from typing import cast

import torch
from torch import Tensor, nn


class EdgeMaxConv(nn.Module):
    r"""One TacGNN layer (Yang et al., "TacGNN", RA-L 2023; EdgeConv of Wang et al., 2019).

    .. math::
        h_i' = \mathrm{ReLU}\Big(\max_{j \in \mathcal{N}(i)}
               \phi\big([h_i,\ h_j,\ x_j - x_i]\big)\Big),
        \qquad \phi = \mathrm{Lin}_L \circ \mathrm{ReLU} \circ \dots \circ \mathrm{ReLU} \circ \mathrm{Lin}_1

    :math:`\phi` maps :math:`2 C_{in} + 3 \to C` with ``layers`` Linear layers.

    :meth:`forward` prepares per-node terms and propagates over the edges;
    :meth:`message` is the per-edge function, :meth:`aggregate` the max over a node's
    neighbours and :meth:`update` what follows it. Rewritten for speed, exactly in real
    arithmetic:

    * :math:`\mathrm{Lin}_1` is split by input block,
      :math:`W [h_i, h_j, x_j - x_i] + b = a_i + c_j` with
      :math:`a_i = W_i h_i - W_x x_i + b` and :math:`c_j = W_j h_j + W_x x_j`:
      per-node matmuls; the edges only gather and add;
    * the bias of :math:`\mathrm{Lin}_L` and the final ReLU come after the max
      (:math:`\max_j (z_j + b) = \max_j z_j + b`; ReLU is monotone);
    * every node has exactly K neighbour slots (a graph builder fills missing ones with
      a repeated neighbour, which does not change a max), so the max is an ``amax``
      over a ``(K, n, C)`` tensor: no scatter;
    * edges go in chunks of :attr:`chunk_size` nodes, in place where autograd allows:
      small temporaries stay in cache and are reused by malloc (measured ~1.5x faster
      than one ``(K, V, C)`` tensor).

    Args:
        in_channels: :math:`C_{in}`, node feature width.
        out_channels: :math:`C`.
        layers: Linear layers of :math:`\phi`, at least 2 (default 2, the paper's).

    Shapes:
        - **input:** ``h (V, C_in)`` node features, ``pos (V, 3)`` node positions,
          ``neighbours (K, V)``: row ``k`` holds the ``k``-th neighbour of every node
        - **output:** ``(V, C)``
    """

    chunk_size: int = 4096

    def __init__(self, in_channels: int, out_channels: int, layers: int = 2) -> None:
        super().__init__()
        if layers < 2:
            raise ValueError(f"layers must be >= 2, got {layers}")
        self.in_channels, self.out_channels = in_channels, out_channels
        self.lin1 = nn.Linear(2 * in_channels + 3, out_channels)
        self.hidden = nn.ModuleList(nn.Linear(out_channels, out_channels) for _ in range(layers - 2))
        self.lin2 = nn.Linear(out_channels, out_channels)

    def reset_parameters(self) -> None:
        self.lin1.reset_parameters()
        for lin in self._hidden():
            lin.reset_parameters()
        self.lin2.reset_parameters()

    def forward(self, h: Tensor, pos: Tensor, neighbours: Tensor) -> Tensor:
        if neighbours.shape[1] == 0:
            return h.new_zeros(0, self.out_channels)
        W_i, W_j, W_x = self.lin1.weight.split([self.in_channels, self.in_channels, 3], dim=1)
        hx = torch.cat([h, pos], 1)
        a = torch.addmm(self.lin1.bias, hx, torch.cat([W_i, -W_x], 1).t())  # target terms a_i (V, C)
        c = hx @ torch.cat([W_j, W_x], 1).t()  # source terms c_j (V, C)
        return self.update(self.propagate(a, c, neighbours))

    def propagate(self, a: Tensor, c: Tensor, neighbours: Tensor) -> Tensor:
        """Messages of every edge ``j -> i``, aggregated per target, chunk by chunk of targets."""
        K, V = neighbours.shape
        out = []
        for lo in range(0, V, self.chunk_size):
            nbr = neighbours[:, lo : lo + self.chunk_size]
            n = nbr.shape[1]
            c_j = c.index_select(0, nbr.reshape(-1)).view(K, n, -1)
            out.append(self.aggregate(self.message(a[lo : lo + n], c_j)))
        return out[0] if len(out) == 1 else torch.cat(out)

    def message(self, a_i: Tensor, c_j: Tensor) -> Tensor:
        r""":math:`\phi([h_i, h_j, x_j - x_i])` without the last bias, from the split first layer.

        ``a_i (n, C)``, ``c_j (K, n, C)`` (a fresh gather, overwritten) -> ``(K, n, C)``.
        """
        K, n, C = c_j.shape
        e = c_j.add_(a_i).relu_().view(K * n, C)
        for lin in self._hidden():
            e = torch.addmm(lin.bias, e, lin.weight.t()).relu_()
        return (e @ self.lin2.weight.t()).view(K, n, -1)

    def _hidden(self) -> list[nn.Linear]:
        """The hidden layers, typed as Linear (a ModuleList iterates as plain Modules)."""
        return cast("list[nn.Linear]", self.hidden)

    def aggregate(self, messages: Tensor) -> Tensor:
        """Max over each node's K neighbour slots: ``(K, n, C) -> (n, C)``."""
        return messages.amax(0)

    def update(self, aggregated: Tensor) -> Tensor:
        """The last bias and the ReLU, after the max."""
        return (aggregated + self.lin2.bias).relu_()

    def __repr__(self) -> str:
        return (f"{self.__class__.__name__}({self.in_channels}, {self.out_channels}, "
                f"layers={len(self.hidden) + 2})")
