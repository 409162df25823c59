"""Image products of a finished tile: the background (:mod:`.background`), normalisation
and dynamic range compression (:mod:`.drc`), detections (:mod:`.detect`), quicklooks
(:mod:`.quicklook`), and the chain that runs them and saves a tile (:mod:`.chain`)."""
