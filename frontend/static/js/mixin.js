// A panel's class whose methods live in several modules, one job each: mixin(Panel, PartA, PartB) copies each
// part's methods onto the panel's prototype (`this` is the panel in every one). A name defined twice is an error.

export function mixin(target, ...parts) {
  for (const part of parts) {
    for (const name of Object.getOwnPropertyNames(part.prototype)) {
      if (name === "constructor") continue;
      if (Object.prototype.hasOwnProperty.call(target.prototype, name)) {
        throw new Error(`${target.name}.${name} is defined twice (in ${part.name} too)`);
      }
      Object.defineProperty(target.prototype, name, Object.getOwnPropertyDescriptor(part.prototype, name));
    }
  }
  return target;
}
