"""Functional ops with ``torch.nn.functional``'s names, arguments and defaults.

Each op is a ``Function`` whose forward and backward call one Rust kernel pair in ``mipnet._core``.
One module per op family; this package re-exports them all.
"""

from ._act import *  # noqa: F401,F403
from ._conv import *  # noqa: F401,F403
from ._corr import *  # noqa: F401,F403
from ._elementwise import *  # noqa: F401,F403
from ._gate import *  # noqa: F401,F403
from ._gru import *  # noqa: F401,F403
from ._loss import *  # noqa: F401,F403
from ._norm import *  # noqa: F401,F403
from ._pad import *  # noqa: F401,F403
from ._pool import *  # noqa: F401,F403
from ._sample import *  # noqa: F401,F403
from ._shape import *  # noqa: F401,F403
from ._softmax import *  # noqa: F401,F403
from ._upsample import *  # noqa: F401,F403
