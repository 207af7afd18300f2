"""The three networks (Marker Localizer, Marker Recognizer, Crosspoint Localizer) and the Detector."""
