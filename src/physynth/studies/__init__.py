"""Studies built on the generator: anchor count x channel regime (:mod:`.anchors`), anchor placement
(:mod:`.placement`), the channel regimes they share (:mod:`.regimes`), anchor subsets (:mod:`.subset`) and
GDOP along a path (:mod:`.dop`). Heavy modules are imported by the caller, not here."""
