"""The incremental synthetic benchmark (paper, "Incremental synthetic data benchmark")."""

from railwatch.synthetic.datasets import SyntheticSet, generate
from railwatch.synthetic.stages import SPEC_VERSION, STAGES, StageConfig, stage

__all__ = ["SPEC_VERSION", "STAGES", "StageConfig", "SyntheticSet", "generate", "stage"]
