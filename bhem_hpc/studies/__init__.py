"""Accuracy-versus-cost studies: one module per study (:mod:`.plate`, :mod:`.buckling`, :mod:`.drape`,
:mod:`.wrinkle`, :mod:`.cantilever`), the study record (:mod:`.study`), the registry and the runner
that writes tables, plots and the accuracy-cost page (:mod:`.report`), and the reference solutions
(:mod:`.references`)."""
