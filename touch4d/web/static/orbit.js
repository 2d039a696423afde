// The desktop view: an orbit camera around the 3D screen, dragged with the mouse, zoomed with the wheel.

import { lookAt } from './mat.js';

export class Orbit {
  constructor(element, camera) {
    this.yaw = camera.yaw;          // degrees about +y, 0 = looking from +z
    this.pitch = camera.pitch;      // degrees up from the xz plane
    this.distance = camera.distance;
    this.target = camera.target;
    this.fov = camera.fov;
    let last = null;
    element.addEventListener('pointerdown', (e) => { last = [e.clientX, e.clientY]; element.setPointerCapture(e.pointerId); });
    element.addEventListener('pointerup', () => { last = null; });
    element.addEventListener('pointermove', (e) => {
      if (!last) return;
      this.yaw -= 0.3 * (e.clientX - last[0]);
      this.pitch = Math.min(89, Math.max(-89, this.pitch + 0.3 * (e.clientY - last[1])));
      last = [e.clientX, e.clientY];
    });
    element.addEventListener('wheel', (e) => {
      e.preventDefault();
      this.distance = Math.min(40, Math.max(1.5, this.distance * Math.exp(0.001 * e.deltaY)));
    }, { passive: false });
  }

  view() {
    const y = (this.yaw * Math.PI) / 180, p = (this.pitch * Math.PI) / 180;
    const t = this.target;
    const eye = [t[0] + this.distance * Math.cos(p) * Math.sin(y), t[1] + this.distance * Math.sin(p),
                 t[2] + this.distance * Math.cos(p) * Math.cos(y)];
    return lookAt(eye, t);
  }
}
