"""Open ray-traced cities: writers of Wireless InSite exports and (with the raytrace extra) Sionna RT scenes."""
