"""SECOND modules under their OpenPCDet names and state-dict layout."""
