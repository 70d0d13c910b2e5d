"""Where B comes from: thruster geometry -> effectiveness, thruster curves."""
