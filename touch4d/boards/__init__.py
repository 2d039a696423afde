"""The glove's CAN motor boards: protocol (DBC), duty mapping, driver, link and board emulator."""
