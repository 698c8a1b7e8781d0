"""How each method looks in the report's charts."""

#: Marker and colour per method in the charts.
STYLE = {
    "discs": ("s", "#7f7f7f"), "surfels-paper": ("^", "#1f77b4"),
    "surfels-smooth": ("o", "#2ca02c"), "poisson": ("D", "#d62728"),
    "ball-pivoting": ("v", "#9467bd"), "alpha-shape": ("P", "#ff7f0e"),
}
