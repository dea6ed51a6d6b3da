"""The CAN message layer of a controller: frames, signals and their layouts, read by the C
generator and the bench alike."""
