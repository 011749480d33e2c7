"""Earth model, batched strapdown INS (ENU) with its 15-state error model, and alignment.

Pure numpy. See `navlab.ins.earth` for frame conventions and `navlab.ins.strapdown` for the
error-state sign convention (error = INS - truth).
"""

from navlab.ins import align, earth, strapdown
from navlab.ins.align import AlignmentResult, align_static, body_to_vehicle, course_heading
from navlab.ins.strapdown import (
    ImuBlock,
    InsState,
    apply_correction,
    discretise,
    error_model_FG,
    init_state,
    mechanise_step,
    propagate_block,
)

__all__ = [
    "AlignmentResult",
    "ImuBlock",
    "InsState",
    "align",
    "align_static",
    "apply_correction",
    "body_to_vehicle",
    "course_heading",
    "discretise",
    "earth",
    "error_model_FG",
    "init_state",
    "mechanise_step",
    "propagate_block",
    "strapdown",
]
