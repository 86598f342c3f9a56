"""The incremental synthetic benchmark (paper, "Incremental synthetic data benchmark")."""

from railwatch.synthetic.datasets import generate, stage_examples
from railwatch.synthetic.stages import SPEC_VERSION, STAGES, StageConfig, stage

__all__ = ["SPEC_VERSION", "STAGES", "StageConfig", "generate", "stage", "stage_examples"]
