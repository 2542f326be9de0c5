"""Augmented reality from a monocular video with cuts and tears (thesis chapter 7).

A registered volumetric model follows an object seen by one camera: image features are
tracked (:mod:`.features`), lifted to 3D (:mod:`.lifting`) and pull the model with springs
(eq. 7.2); where the model cannot follow, a cut is detected (:mod:`.detection`, 7.5) and
made with the chapter 5 cutter, and internal structures are carried along
(:mod:`.internal`, 7.5.4). :mod:`.synth` makes synthetic captures with ground truth.
"""
