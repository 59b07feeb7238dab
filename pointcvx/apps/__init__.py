"""Applications on top of :func:`pointcvx.decompose`: many shapes at once (:mod:`.batch`) and the
benchmark against CoACD and V-HACD (:mod:`.bench`), with what they share (:mod:`.common`)."""
