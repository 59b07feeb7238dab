"""Training data for the feature field: procedural solids (:mod:`.shapes`), prepared samples and
datasets (:mod:`.data`), input augmentation (:mod:`.augment`)."""
