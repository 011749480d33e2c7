"""Leaderboard: the last `navlab bench` — every filter tuned on the same budget, judged on test seeds."""

from navlab.ui import leaderboard
from navlab.ui.frame import frame

frame(
    "Leaderboard",
    "🏆",
    "Every registered filter, each tuned on the same budget on training seeds, judged on test "
    "seeds over a fixed suite of problems, and measured against the floor no estimator can beat.",
)
leaderboard.show()
