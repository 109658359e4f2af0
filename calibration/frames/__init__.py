"""Frames and days: the frame check and framed fit (``check``), the refusals of a training set (``policy``), the
mocap-world/flange registration, the rebase of a model onto a new day and its design, the multi-day fit and the
differences between days (``day_tests``, ``days_problem``, ``daydiff``)."""
