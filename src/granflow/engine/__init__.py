"""The numba discrete particle (DPM) engine for periodic chute flows (Weinhart et al. 2012 §2, §5).

* :mod:`.species` — contact species (t_c, e, ...) to per-reduced-mass stiffness and damping
* :mod:`.lib.kernels` — numba kernels (contact laws, neighbour lists, velocity Verlet)
* :mod:`.system` — :class:`ParticleSystem`, the complete dynamic state with checkpoints
* :mod:`.chute` — rough-base preparation, flow insertion, chute set-up (physics.md §3)
* :mod:`.run` — run orchestration: sampling, checkpoint/resume, outputs
"""

from .species import ContactSpecies, InteractionTable
from .system import ParticleSystem, SimulationError

__all__ = ["ContactSpecies", "InteractionTable", "ParticleSystem", "SimulationError"]
