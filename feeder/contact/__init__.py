"""Contact model: Greenwood–Williamson + Hertz real contact area and breakaway force (paper §III)."""
