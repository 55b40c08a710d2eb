"""The solver: one vehicle's cuboid from its clicks (the paper's three stages, :mod:`.fit`), and what a fit is made of.

:mod:`.fit` (:func:`~.fit.fit_vehicle`, :class:`~.fit.SolverOptions`, :class:`~.fit.FitResult`) chains starting yaws
from image lines (:mod:`.init`), coordinate descent on the 3D cost (:mod:`.descent`) and Levenberg-Marquardt on the
pixel cost (:mod:`.refine`, over the generic :mod:`.lm`) on the problem of one vehicle (:mod:`.problem`), with the
robust loss (:mod:`.robust`), the plausibility check (:mod:`.plausibility`), the reasons clicks cannot give a cuboid
(:mod:`.degenerate`), the fallback starts (:mod:`.fallback`), the chi-square test of a fit's residuals (:mod:`.misfit`),
its uncertainty and observability (:mod:`.uncertainty`, :mod:`.observability`), the guidance on what to click next
(:mod:`.guidance`) and the joint refinement of an image's vehicles on their ground plane (:mod:`.joint`). Nothing here
imports pydantic or anything above the parts.
"""
